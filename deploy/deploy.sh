#!/usr/bin/env bash
# deploy/deploy.sh up|down|ps: the compose system of deploy/compose.yaml (`make deploy`, `make deploy-down`).
#
#   up     TLS material and config into deploy/.build (certificates by deploy/certs/make-certs.sh when
#          missing, deploy/roles.toml copied), images by deploy/images/build.sh (cached), then
#          `docker-compose -f deploy/compose.yaml -p zenoh-nc up -d`, waits until every service is
#          healthy (ZNC_UP_TIMEOUT s, 240) and prints how to watch it.
#   down   `docker-compose ... down` (containers and networks; images stay).
#   ps     the services and their health.
# Environment: ZNC_DRIVES (1: also deploy/compose.drives.yaml: nc1's axes 1, 2 on drives in the container
# nc-drives), ZNC_STANDBY (1: also deploy/compose.standby.yaml over compose.drives.yaml: nc1 as a hot-standby pair,
# services nc1 (node a) and nc1b (node b), docs/standby.md; implies ZNC_DRIVES=1), ZNC_PROJECT (compose project, zenoh-nc), ZNC_TRANSPORT (tls, or tcp), ZNC_ROUTER_PORT
# (7450: the router on 127.0.0.1 for status tools), ZNC_COMPOSE (the compose command: docker-compose,
# else `docker compose`), PYTHON (for build.sh). Exit code 0 ok, 1 failure (what failed on stderr).
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
BUILD="$HERE/.build"
PROJECT="${ZNC_PROJECT:-zenoh-nc}"
export ZNC_TRANSPORT="${ZNC_TRANSPORT:-tls}"
export ZNC_ROUTER_PORT="${ZNC_ROUTER_PORT:-7450}"
SERVICES=(router nc1 nc2 plc1 plc2 opcua web)
IDS=(nc1 nc2 plc1 plc2 status opcua web drives1)   # one certificate each (+ router, always; status: an observer for tools;
                                               # drives1: the drive host of compose.drives.yaml)
APP_UID=10001                           # the image's user (deploy/images/Dockerfile)

log() { printf 'deploy.sh: %s\n' "$*" >&2; }
die() { log "error: $*"; exit 1; }

if [[ -n ${ZNC_COMPOSE:-} ]]; then
    read -r -a COMPOSE <<<"$ZNC_COMPOSE"
elif command -v docker-compose >/dev/null 2>&1; then
    COMPOSE=(docker-compose)
else
    COMPOSE=(docker compose)
fi
FILES=(-f "$HERE/compose.yaml")
[[ ${ZNC_STANDBY:-0} != 1 ]] || ZNC_DRIVES=1   # the pair needs drives that outlive either NC
if [[ ${ZNC_DRIVES:-0} == 1 ]]; then   # nc1's axes 1, 2 on remote drives in their own container
    FILES+=(-f "$HERE/compose.drives.yaml")
    SERVICES+=(nc-drives)
fi
if [[ ${ZNC_STANDBY:-0} == 1 ]]; then  # nc1's second node (standby) in its own container
    FILES+=(-f "$HERE/compose.standby.yaml")
    SERVICES+=(nc1b)
fi
compose() { "${COMPOSE[@]}" "${FILES[@]}" -p "$PROJECT" "$@"; }

# certificates (mutual TLS, private CA) and the router's roles file, as the containers mount them
prepare() {
    mkdir -p "$BUILD/certs" "$BUILD/etc"
    if [[ -f $HERE/roles.toml ]]; then
        cp "$HERE/roles.toml" "$BUILD/etc/roles.toml"
    elif [[ $ZNC_TRANSPORT == tls ]]; then
        die "ZNC_TRANSPORT=tls needs deploy/roles.toml"
    fi
    local id missing=0
    for id in router "${IDS[@]}"; do
        [[ -s $BUILD/certs/$id.pem ]] || missing=1   # (an older .build without drives1's: made now, same CA)
    done
    if [[ ! -s $BUILD/certs/ca.pem || $missing == 1 ]]; then
        if [[ -x $HERE/certs/make-certs.sh ]]; then
            log "making certificates (private CA) in $BUILD/certs for ${IDS[*]}"
            "$HERE/certs/make-certs.sh" "$BUILD/certs" "${IDS[@]}" >&2 || die "make-certs.sh failed"
        elif [[ $ZNC_TRANSPORT == tls ]]; then
            die "ZNC_TRANSPORT=tls needs deploy/certs/make-certs.sh"
        fi
    fi
    # the containers run as uid:gid $APP_UID: their keys readable by that group; the CA key stays root's
    local key
    for key in "$BUILD"/certs/*.key; do
        [[ -e $key && $(basename "$key") != ca.key ]] || continue
        chgrp "$APP_UID" "$key" && chmod 0640 "$key"
    done
    [[ ! -e $BUILD/certs/ca.key ]] || { chgrp root "$BUILD/certs/ca.key" && chmod 0600 "$BUILD/certs/ca.key"; }
}

# nc-opcua's users file (user `operator`, a random password kept in operator.password, 0600) and its OPC UA
# application certificate (ApplicationUri urn:zenoh-nc:deploy:opcua), made once with the image's own nc-opcua
prepare_opcua() {
    local dir="$BUILD/opcua"
    mkdir -p "$dir"
    local run=(docker run --rm -i --user 0 -v "$dir:/out" "${ZNC_IMAGE:-zenoh-nc:latest}" python -m nc_opcua)
    if [[ ! -s $dir/users.toml ]]; then
        (umask 077 && openssl rand -base64 18 >"$dir/operator.password") || die "cannot make a password"
        "${run[@]}" user /out/users.toml operator --role operator <"$dir/operator.password" >&2 \
            || die "nc-opcua user failed"
        log "nc-opcua user 'operator': password in $dir/operator.password"
    fi
    if [[ ! -s $dir/opcua.der ]]; then
        "${run[@]}" cert /out --name opcua --uri urn:zenoh-nc:deploy:opcua --host localhost --host 127.0.0.1 \
            --host opcua >&2 || die "nc-opcua cert failed"
    fi
    # the container runs as uid:gid $APP_UID: the users file and the key readable by that group only
    chgrp "$APP_UID" "$dir/users.toml" "$dir/opcua.key.pem" && chmod 0640 "$dir/users.toml" "$dir/opcua.key.pem"
}

# nc-web's users file (user `operator`, a random password kept in operator.password, 0600), made once with the
# image's own nc-web, and its cookie secret (32 random bytes, hex)
prepare_web() {
    local dir="$BUILD/web"
    mkdir -p "$dir"
    if [[ ! -s $dir/users.toml ]]; then
        (umask 077 && openssl rand -base64 18 >"$dir/operator.password") || die "cannot make a password"
        docker run --rm -i --user 0 -v "$dir:/out" "${ZNC_IMAGE:-zenoh-nc:latest}" python -m nc_web user \
            /out/users.toml operator --role operator <"$dir/operator.password" >&2 || die "nc-web user failed"
        log "nc-web user 'operator': password in $dir/operator.password"
    fi
    [[ -s $dir/secret ]] || (umask 077 && openssl rand -hex 32 >"$dir/secret") || die "cannot make nc-web's secret"
    chgrp "$APP_UID" "$dir/users.toml" "$dir/secret" && chmod 0640 "$dir/users.toml" "$dir/secret"
}

wait_healthy() {
    local deadline=$((SECONDS + ${ZNC_UP_TIMEOUT:-240})) s id state all
    while :; do
        all=1
        local line=()
        for s in "${SERVICES[@]}"; do
            id=$(compose ps -q "$s" 2>/dev/null || true)
            state=$([[ -n $id ]] && docker inspect -f '{{if .State.Health}}{{.State.Health.Status}}{{else}}{{.State.Status}}{{end}}' "$id" 2>/dev/null || echo missing)
            line+=("$s=$state")
            [[ $state == healthy ]] || all=0
        done
        if ((all)); then
            log "healthy: ${line[*]}"
            return 0
        fi
        if ((SECONDS >= deadline)); then
            log "not healthy after ${ZNC_UP_TIMEOUT:-240} s: ${line[*]}"
            compose logs --tail 20 >&2 || true
            return 1
        fi
        sleep 2
    done
}

case "${1:-}" in
    up)
        prepare
        PYTHON="${PYTHON:-python3}" "$HERE/images/build.sh"
        prepare_opcua
        prepare_web
        compose up -d
        wait_healthy || die "the system did not become healthy"
        c="${COMPOSE[*]} -f deploy/compose.yaml"
        [[ ${ZNC_DRIVES:-0} != 1 ]] || c+=" -f deploy/compose.drives.yaml"
        [[ ${ZNC_STANDBY:-0} != 1 ]] || c+=" -f deploy/compose.standby.yaml"
        c+=" -p $PROJECT"
        cat <<EOF
zenoh-nc is up (project $PROJECT, transport $ZNC_TRANSPORT): ${SERVICES[*]}.
  $c ps                  # services and health
  $c logs -f plc1 plc2   # the PLC programs' events (moves, errors, power)
  $c logs -f nc1         # an NC server's log
EOF
        if [[ ${ZNC_DRIVES:-0} == 1 ]]; then
            cat <<EOF
  $c logs -f nc-drives   # the drive host (nc-drive-sim drives1: nc1's axes 1, 2); docker kill nc1 and its
                         # drives stop on their quick-stop ramp (0x8130) after ZNC_DRIVE_TIMEOUT_S (0.1 s), positions kept
EOF
        fi
        if [[ ${ZNC_STANDBY:-0} == 1 ]]; then
            cat <<EOF
  $c logs -f nc1 nc1b    # the hot-standby pair (nodes a, b); docker kill / pause the active one's container:
                         # the other takes over (nc-status: the ha: line), the drives go on (ZNC_DRIVE_TIMEOUT_S 1 s)
EOF
        fi
        cat <<EOF
  make deploy-down       # stop and remove it
  OPC UA: opc.tcp://127.0.0.1:${ZNC_OPCUA_PORT:-4840}/zenoh-nc, user operator, password in deploy/.build/opcua/operator.password
          (Basic256Sha256; the server certificate deploy/.build/opcua/opcua.der)
  Web: http://127.0.0.1:${ZNC_WEB_PORT:-8080}/, user operator, password in deploy/.build/web/operator.password
EOF
        if [[ $ZNC_TRANSPORT == tcp ]]; then
            echo "  nc-status --connect tcp/127.0.0.1:$ZNC_ROUTER_PORT   # live table of the NCs (the router on the host's loopback)"
        else
            echo "  nc-status --connect tls/127.0.0.1:$ZNC_ROUTER_PORT --tls-dir deploy/.build/certs   # as the observer 'status'"
        fi
        ;;
    down)
        compose down -t 15
        ;;
    ps)
        compose ps
        ;;
    *)
        sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'
        exit 2
        ;;
esac
