#!/usr/bin/env bash
# deploy/images/build.sh: build the zenoh-nc container images on this machine, without a registry.
#
#   deploy/images/build.sh            # what `make images` runs
#   PYTHON=.venv/bin/python deploy/images/build.sh
#
# Steps, each skipped when its result exists (tags are content hashes of the step's inputs, so a
# rerun with nothing changed takes seconds):
#   1. base image  zenoh-nc-base:<hash>  a minimal Debian bookworm root (debootstrap, variant
#      minbase, + python3 python3-venv ca-certificates iproute2 procps openssl), `docker import`ed.
#      Inputs: suite, mirror, package list, BASE_RECIPE. debootstrap is apt-get installed if missing.
#   2. wheels on the host, into deploy/.build/wheels: the dependencies for CPython 3.11 (bookworm's
#      python3) manylinux x86_64 (`pip download`), the build tools, and the project's own wheel
#      (`pip wheel`, from a copy of the sources).
#   3. app image   zenoh-nc:<hash> (+ zenoh-nc:latest)  FROM the base, the wheels installed offline
#      (`pip install --no-index --find-links`) into /opt/zenoh-nc, with deploy/programs and the
#      entry scripts. Inputs: the base tag, pyproject.toml, the packages' and schema/ sources,
#      deploy/images/{Dockerfile,znc-run,znc-health}, deploy/programs.
#      One image for router, NC server and PLC runtime (`znc-run router|nc|plc`).
# Prints what it built and what it reused. Exit codes: 0 success; 1 failure (message on stderr);
# 3 no docker engine reachable; 4 a download failed (apt-get, debootstrap, pip: no network?).
# Environment: PYTHON (python with pip for the host steps, default python3), ZNC_BUILD_DIR
# (default deploy/.build), ZNC_DEBIAN_MIRROR (default http://deb.debian.org/debian), ZNC_KEEP_IMAGES
# (1: older zenoh-nc:<hash> images are kept, not removed).
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
BUILD="${ZNC_BUILD_DIR:-$ROOT/deploy/.build}"
PYTHON="${PYTHON:-python3}"
SUITE=bookworm
MIRROR="${ZNC_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
PACKAGES="python3,python3-venv,ca-certificates,iproute2,procps,openssl"
BASE_RECIPE=1            # bump when the way the base root is made changes
PY_TAG=311               # bookworm's python3 is CPython 3.11: the wheels must match it
# bookworm's glibc is 2.36: every manylinux tag up to 2_36 fits (pip does not expand manylinux_2_X itself)
PLATFORMS=(manylinux2014_x86_64 $(for m in $(seq 17 36); do printf 'manylinux_2_%s_x86_64 ' "$m"; done))

log() { printf 'build.sh: %s\n' "$*" >&2; }
die() { log "error: $*"; exit 1; }
die_net() { log "error: $* (no network?)"; exit 4; }   # a download failed
now() { date +%s.%N; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }
image_exists() { docker image inspect "$1" >/dev/null 2>&1; }
sha() { sha256sum | cut -c1-16; }

SUMMARY=()
T0=$(now)

docker info >/dev/null 2>&1 || { log "error: docker engine not reachable (docker info failed)"; exit 3; }
mkdir -p "$BUILD"
# one build at a time (make images and a test session may start together)
exec 9>"$BUILD/.lock"
flock 9

# ---- 1. base image ---------------------------------------------------------------------------
BASE_HASH=$(printf '%s\n' "$SUITE" "$MIRROR" "$PACKAGES" "minbase" "$BASE_RECIPE" | sha)
BASE_TAG="zenoh-nc-base:$BASE_HASH"
t=$(now)
if image_exists "$BASE_TAG"; then
    SUMMARY+=("base  $BASE_TAG  reused")
else
    tarball="$BUILD/base/$BASE_HASH.tar"
    if [[ ! -s $tarball ]]; then
        if ! command -v debootstrap >/dev/null 2>&1; then
            log "installing debootstrap (apt-get)"
            export DEBIAN_FRONTEND=noninteractive
            apt-get update -qq >&2 || die_net "apt-get update failed"
            apt-get install -y -qq debootstrap >&2 || die_net "apt-get install debootstrap failed"
        fi
        rootfs="$BUILD/base/rootfs-$BASE_HASH"
        rm -rf "$rootfs"
        mkdir -p "$rootfs"
        log "debootstrap $SUITE (minbase + $PACKAGES) from $MIRROR into $rootfs"
        if ! debootstrap --variant=minbase --include="$PACKAGES" "$SUITE" "$rootfs" "$MIRROR" \
                >"$BUILD/base/debootstrap-$BASE_HASH.log" 2>&1; then
            tail -n 20 "$BUILD/base/debootstrap-$BASE_HASH.log" >&2
            rm -rf "$rootfs"
            die_net "debootstrap failed (log: $BUILD/base/debootstrap-$BASE_HASH.log)"
        fi
        # what an image does not need: package caches and lists, logs
        rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/log/*.log
        tar -C "$rootfs" --numeric-owner -cf "$tarball.part" .
        mv "$tarball.part" "$tarball"
        rm -rf "$rootfs"
    fi
    docker import --change 'ENV LANG=C.UTF-8' --change 'CMD ["/bin/bash"]' \
        -m "zenoh-nc base: debian $SUITE minbase + $PACKAGES" "$tarball" "$BASE_TAG" >/dev/null \
        || die "docker import of $tarball failed"
    SUMMARY+=("base  $BASE_TAG  built in $(since "$t") s")
fi

# ---- 3 (inputs first): the app image's content hash ------------------------------------------
# the top-level Python packages, from pyproject.toml's [tool.setuptools] packages (one list to keep)
PKG_TOPS=$("$PYTHON" - "$ROOT/pyproject.toml" <<'EOF'
import sys, tomllib
pk = tomllib.load(open(sys.argv[1], "rb"))["tool"]["setuptools"]["packages"]
print(" ".join(sorted({p.split(".")[0] for p in pk})))
EOF
) || die "cannot read the packages of $ROOT/pyproject.toml"
app_inputs() {
    # every file that ends up in the image, relative to ROOT, sorted (no caches)
    # shellcheck disable=SC2086  # PKG_TOPS: words on purpose
    (cd "$ROOT" && find pyproject.toml README.md $PKG_TOPS schema \
        deploy/images/Dockerfile deploy/images/znc-run deploy/images/znc-health deploy/programs \
        -type f ! -path '*/__pycache__/*' ! -name '*.pyc' 2>/dev/null | LC_ALL=C sort)
}
APP_HASH=$( { echo "$BASE_TAG $PY_TAG ${PLATFORMS[*]}"; cd "$ROOT"; app_inputs | xargs sha256sum; } | sha)
APP_TAG="zenoh-nc:$APP_HASH"
if image_exists "$APP_TAG"; then
    SUMMARY+=("app   $APP_TAG  reused")
    docker tag "$APP_TAG" zenoh-nc:latest
else
    # ---- 2. wheels -------------------------------------------------------------------------------
    WHEELS="$BUILD/wheels"
    mkdir -p "$WHEELS"
    "$PYTHON" -m pip --version >/dev/null 2>&1 || die "$PYTHON has no pip (set PYTHON=...)"
    t=$(now)
    # a venv with the build backend (setuptools, wheel) once: later wheels build offline and fast
    buildenv="$BUILD/buildenv"
    if [[ ! -e $buildenv/.done ]]; then
        rm -rf "$buildenv"
        { "$PYTHON" -m venv "$buildenv" \
          && "$buildenv/bin/python" -m pip install -q "setuptools>=68" wheel; } >&2 \
            || die_net "cannot make the build venv $buildenv (pip install setuptools wheel)"
        touch "$buildenv/.done"
        SUMMARY+=("build venv (setuptools, wheel)  made in $(since "$t") s")
    fi
    # the project's wheel, built from a copy of exactly the hashed sources
    t=$(now)
    src="$BUILD/src-$APP_HASH"
    rm -rf "$src" && mkdir -p "$src"
    (cd "$ROOT" && app_inputs | grep -v '^deploy/' | tar -cf - -T -) | tar -C "$src" -xf -
    proj="$WHEELS/project-$APP_HASH"
    rm -rf "$proj"
    if ! "$buildenv/bin/python" -m pip wheel -q --no-deps --no-index --no-build-isolation -w "$proj" "$src" \
            >"$BUILD/pip-wheel.log" 2>&1; then
        tail -n 30 "$BUILD/pip-wheel.log" >&2
        die "pip wheel of the project failed (log: $BUILD/pip-wheel.log)"
    fi
    rm -rf "$src"
    whl=$(ls "$proj"/zenoh_nc-*.whl)
    # every package of the sources must be in the wheel (pyproject lists them one by one)
    "$PYTHON" - "$ROOT" "$whl" $PKG_TOPS <<'EOF' || die "the wheel misses packages: add them to [tool.setuptools] packages in pyproject.toml"
import pathlib, sys, zipfile
root, names = pathlib.Path(sys.argv[1]), zipfile.ZipFile(sys.argv[2]).namelist()
have = {n.rsplit("/", 1)[0] for n in names if n.endswith("/__init__.py")}
want = {p.parent.relative_to(root).as_posix() for top in sys.argv[3:]
        for p in (root / top).rglob("__init__.py") if "__pycache__" not in p.parts}
missing = sorted(want - have)
schema = any(n.startswith("nc_schema/contract/") and n.endswith(".json") for n in names)
if missing or not schema:
    print("build.sh: not in the wheel:", ", ".join(m.replace("/", ".") for m in missing) or "-",
          "" if schema else "(and no schema/*.json as nc_schema/contract)", file=sys.stderr)
    sys.exit(1)
EOF
    SUMMARY+=("wheel $(basename "$whl")  built in $(since "$t") s")
    # its dependencies for the image's python (cp311, manylinux x86_64), cached by their spec
    deps_spec=$("$PYTHON" - "$ROOT/pyproject.toml" <<'EOF'
import sys, tomllib
print("\n".join(tomllib.load(open(sys.argv[1], "rb"))["project"]["dependencies"]))
EOF
)
    DEPS_HASH=$(printf '%s\n%s %s\n' "$deps_spec" "$PY_TAG" "${PLATFORMS[*]}" | sha)
    deps="$WHEELS/deps-$DEPS_HASH"
    t=$(now)
    if [[ -e $deps/.done ]]; then
        SUMMARY+=("wheels deps-$DEPS_HASH  reused")
    else
        rm -rf "$deps"
        mapfile -t reqs <<<"$deps_spec"
        env -u PIP_FIND_LINKS "$PYTHON" -m pip download -q -d "$deps" --only-binary=:all: \
            "${PLATFORMS[@]/#/--platform=}" --python-version "$PY_TAG" --implementation cp --abi "cp$PY_TAG" \
            "${reqs[@]}" >&2 || die_net "pip download of the dependencies failed"
        touch "$deps/.done"
        SUMMARY+=("wheels deps-$DEPS_HASH  downloaded in $(since "$t") s: $(cd "$deps" && ls *.whl | tr '\n' ' ')")
    fi
    # ---- 3. app image ----------------------------------------------------------------------------
    t=$(now)
    ctx="$BUILD/ctx-$APP_HASH"
    rm -rf "$ctx" && mkdir -p "$ctx/deps" "$ctx/app"
    cp "$deps"/*.whl "$ctx/deps/"      # own layer: docker's cache keeps it while the deps stay
    cp "$whl" "$HERE/znc-run" "$HERE/znc-health" "$ctx/app/"
    cp -r "$ROOT/deploy/programs" "$ctx/app/"
    cp "$HERE/Dockerfile" "$ctx/"
    find "$ctx" -name __pycache__ -prune -exec rm -rf {} +
    if ! DOCKER_BUILDKIT=0 docker build --build-arg "BASE=$BASE_TAG" \
            -t "$APP_TAG" -t zenoh-nc:latest "$ctx" \
            >"$BUILD/docker-build-$APP_HASH.log" 2>&1; then
        tail -n 30 "$BUILD/docker-build-$APP_HASH.log" >&2
        die "docker build failed (log: $BUILD/docker-build-$APP_HASH.log)"
    fi
    rm -rf "$ctx" "$proj"
    SUMMARY+=("app   $APP_TAG  built in $(since "$t") s")
    # older app images go (one in use by a container stays: docker rmi refuses it); ZNC_KEEP_IMAGES=1
    # keeps them (several checkouts of the project on one machine, each testing its own image)
    [[ ${ZNC_KEEP_IMAGES:-0} == 1 ]] || for old in $(docker images zenoh-nc --format '{{.Tag}}' | grep -E '^[0-9a-f]{16}$' | grep -vx "$APP_HASH"); do
        docker rmi "zenoh-nc:$old" >/dev/null 2>&1 && SUMMARY+=("app   zenoh-nc:$old  removed (older)") || true
    done
fi

for line in "${SUMMARY[@]}"; do echo "build.sh: $line"; done
echo "build.sh: images ready in $(since "$T0") s: $BASE_TAG, $APP_TAG (= zenoh-nc:latest)"
