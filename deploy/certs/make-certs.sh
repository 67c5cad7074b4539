#!/bin/sh
# make-certs.sh OUTDIR NAME... [--rogue]
#
# A private CA and one certificate per NAME for zenoh-nc's mutual TLS (openssl, EC P-256):
#
#   OUTDIR/ca.pem, ca.key         the CA (made once; reused when OUTDIR already has one)
#   OUTDIR/router.pem, router.key the router's certificate (always made): CN=router,
#                                 SAN DNS:router, DNS:localhost, IP:127.0.0.1
#   OUTDIR/NAME.pem, NAME.key     CN=NAME (the identity the roles file and the ACL use),
#                                 SAN DNS:NAME, DNS:localhost, IP:127.0.0.1, EKU clientAuth and
#                                 serverAuth: the same certificate serves a client (plc1, eng1,
#                                 status) and an NC that listens for its clients (nc1) or connects
#                                 to a router
#   --rogue                       also OUTDIR/rogue/: another CA and certificates for the same
#                                 names, signed by it (tests: a certificate from another CA
#                                 must be refused)
#
# Existing certificates are kept (delete a NAME's files to renew it). Private keys are made
# readable by their owner only. The CA key stays in OUTDIR: keep it off the machines that only
# need ca.pem and their own NAME.pem/NAME.key.
set -eu

usage() { echo "usage: $0 OUTDIR NAME... [--rogue]" >&2; exit 2; }
[ $# -ge 1 ] || usage
OUT=$1; shift
ROGUE=0
NAMES=router
for a in "$@"; do
  case $a in
    --rogue) ROGUE=1 ;;
    -*) usage ;;
    *)
      if ! printf '%s' "$a" | grep -Eq '^[A-Za-z0-9_.-]{1,64}$'; then
        echo "$0: invalid name '$a' (1-64 of letters, digits, '_', '.', '-')" >&2; exit 2
      fi
      case " $NAMES " in *" $a "*) ;; *) NAMES="$NAMES $a" ;; esac ;;
  esac
done
command -v openssl >/dev/null 2>&1 || { echo "$0: openssl not found" >&2; exit 3; }
DAYS=${CERT_DAYS:-3650}

# make_ca DIR CN
make_ca() {
  [ -f "$1/ca.pem" ] && [ -f "$1/ca.key" ] && return 0
  mkdir -p "$1"
  (umask 077; openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:prime256v1 -out "$1/ca.key" 2>/dev/null)
  openssl req -x509 -new -key "$1/ca.key" -sha256 -days "$DAYS" -subj "/CN=$2" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$1/ca.pem"
}

# make_leaf DIR NAME
make_leaf() {
  [ -f "$1/$2.pem" ] && [ -f "$1/$2.key" ] && return 0
  tmp=$(mktemp -d)
  (umask 077; openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:prime256v1 -out "$1/$2.key" 2>/dev/null)
  openssl req -new -key "$1/$2.key" -subj "/CN=$2" -out "$tmp/leaf.csr"
  printf '%s\n' "basicConstraints=critical,CA:FALSE" "keyUsage=critical,digitalSignature,keyEncipherment" \
    "extendedKeyUsage=serverAuth,clientAuth" "subjectAltName=DNS:$2,DNS:localhost,IP:127.0.0.1" > "$tmp/leaf.ext"
  openssl x509 -req -in "$tmp/leaf.csr" -CA "$1/ca.pem" -CAkey "$1/ca.key" -CAcreateserial -CAserial "$tmp/ca.srl" \
    -days "$DAYS" -sha256 -extfile "$tmp/leaf.ext" -out "$1/$2.pem" 2>/dev/null
  rm -rf "$tmp"
}

make_ca "$OUT" zenoh-nc-ca
for n in $NAMES; do make_leaf "$OUT" "$n"; done
if [ "$ROGUE" = 1 ]; then
  make_ca "$OUT/rogue" zenoh-nc-rogue-ca
  for n in $NAMES; do make_leaf "$OUT/rogue" "$n"; done
fi
echo "certificates in $OUT: ca.pem $(for n in $NAMES; do printf '%s.pem ' "$n"; done)$( [ "$ROGUE" = 1 ] && echo "(+ rogue/)")"
