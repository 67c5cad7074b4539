#!/bin/sh
# make-certs.sh OUTDIR [--server NAME]... NAME... [--rogue]
#
# A private CA and one certificate per NAME for zenoh-nc's mutual TLS (openssl, EC P-256):
#
#   OUTDIR/ca.pem, ca.key         the CA (made once; reused when OUTDIR already has one)
#   OUTDIR/router.pem, router.key the router's certificate (always made, a server one: below)
#   OUTDIR/NAME.pem, NAME.key     a client certificate: CN=NAME (the identity the roles file and
#                                 the ACL use), SAN DNS:NAME, EKU clientAuth only (it cannot serve
#                                 a TLS listener): PLC clients, observers (status), and NCs behind a
#                                 router (deploy/compose.yaml)
#   --server NAME                 NAME's certificate also serves a listener: EKU serverAuth and
#                                 clientAuth, SAN DNS:NAME, DNS:localhost, IP:127.0.0.1 (the router;
#                                 an NC that clients reach directly, `nc-server --listen tls/...`)
#   --rogue                       also OUTDIR/rogue/: another CA and certificates for the same
#                                 names, signed by it (tests: a certificate from another CA
#                                 must be refused)
#
# Existing certificates are kept (delete a NAME's files to renew it, e.g. to change its kind).
# Private keys are made readable by their owner only. The CA key stays in OUTDIR: keep it off the
# machines that only need ca.pem and their own NAME.pem/NAME.key (deploy/compose.yaml mounts
# only those into each container).
set -eu

usage() { echo "usage: $0 OUTDIR [--server NAME]... NAME... [--rogue]" >&2; exit 2; }
[ $# -ge 1 ] || usage
OUT=$1; shift
ROGUE=0
NAMES=router
SERVERS=router
check_name() {
  if ! printf '%s' "$1" | grep -Eq '^[A-Za-z0-9_.-]{1,64}$'; then
    echo "$0: invalid name '$1' (1-64 of letters, digits, '_', '.', '-')" >&2; exit 2
  fi
}
add_name() { case " $NAMES " in *" $1 "*) ;; *) NAMES="$NAMES $1" ;; esac; }
while [ $# -gt 0 ]; do
  case $1 in
    --rogue) ROGUE=1 ;;
    --server)
      [ $# -ge 2 ] || usage
      shift; check_name "$1"; add_name "$1"
      case " $SERVERS " in *" $1 "*) ;; *) SERVERS="$SERVERS $1" ;; esac ;;
    -*) usage ;;
    *) check_name "$1"; add_name "$1" ;;
  esac
  shift
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

# make_leaf DIR NAME (a server certificate if NAME is in SERVERS)
make_leaf() {
  [ -f "$1/$2.pem" ] && [ -f "$1/$2.key" ] && return 0
  tmp=$(mktemp -d)
  (umask 077; openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:prime256v1 -out "$1/$2.key" 2>/dev/null)
  openssl req -new -key "$1/$2.key" -subj "/CN=$2" -out "$tmp/leaf.csr"
  case " $SERVERS " in
    *" $2 "*) eku=serverAuth,clientAuth; san="DNS:$2,DNS:localhost,IP:127.0.0.1" ;;
    *) eku=clientAuth; san="DNS:$2" ;;
  esac
  printf '%s\n' "basicConstraints=critical,CA:FALSE" "keyUsage=critical,digitalSignature,keyEncipherment" \
    "extendedKeyUsage=$eku" "subjectAltName=$san" > "$tmp/leaf.ext"
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
