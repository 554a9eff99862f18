#!/usr/bin/env bash
# Podman for the compose test: the engine, podman-compose, the base image and the testbed's image.
#
#   deploy/podman.sh engine   # podman + runc (+ debootstrap) from the distribution, podman-compose
#                             # in a venv of its own, and containers.conf (runc, lower ulimits)
#   deploy/podman.sh base     # the Dockerfile's FROM image: pulled, or made locally with debootstrap
#   deploy/podman.sh build    # the image compose.yaml runs (formation-testbed:latest)
#   deploy/podman.sh env      # the variables the other steps and the test use, as shell assignments
#
# Everything is kept where the machine keeps it: images in podman's store, podman-compose and
# containers.conf under $FORMATION_CACHE (default ~/.cache/formation-testbed), so a second run
# reuses them. No host name is written here: the Debian mirror is read from apt's sources.
set -euo pipefail
cd "$(dirname "$0")/.."

CACHE=${FORMATION_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/formation-testbed}
IMAGE=${FORMATION_IMAGE:-formation-testbed:latest}
BASE=${FORMATION_BASE:-$(awk 'toupper($1) == "FROM" { print $2; exit }' Dockerfile)}  # bench: another tag
COMPOSE_VENV=$CACHE/podman-compose
PODMAN_COMPOSE_VERSION=1.6.0
export CONTAINERS_CONF=$CACHE/containers.conf

say() { printf 'podman.sh: %s\n' "$*" >&2; }
fail() { say "error: $*"; exit 1; }
now() { date +%s.%N; }
took() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo "$@"
  else return 1
  fi
}

engine() {
  local missing=()
  for tool in podman runc; do command -v "$tool" >/dev/null || missing+=("$tool"); done
  if [ "$(id -u)" = 0 ] && ! command -v debootstrap >/dev/null; then missing+=(debootstrap); fi
  if [ ${#missing[@]} -gt 0 ]; then
    command -v apt-get >/dev/null ||
      fail "no container engine: ${missing[*]} missing and no apt-get to install them; install podman and runc, or run the compose test under Docker (README, Deployment)"
    say "installing ${missing[*]} (apt-get)"
    as_root apt-get update -qq ||
      fail "no container engine: cannot run apt-get as root to install ${missing[*]}"
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq podman runc debootstrap >/dev/null ||
      fail "no container engine: apt-get could not install podman, runc and debootstrap"
  fi
  if [ ! -x "$COMPOSE_VENV/bin/podman-compose" ]; then
    say "installing podman-compose $PODMAN_COMPOSE_VERSION into $COMPOSE_VENV"
    python3 -m venv "$COMPOSE_VENV" || fail "python3 -m venv failed (install python3-venv)"
    "$COMPOSE_VENV/bin/pip" install --quiet "podman-compose==$PODMAN_COMPOSE_VERSION" ||
      fail "pip could not install podman-compose"
  fi
  mkdir -p "$CACHE"
  # runc: crun fails here with "cgroups in hybrid mode not supported". The ulimits stay below
  # the machine's hard limits, which are lower than podman's defaults.
  local nofile nproc
  nofile=$(ulimit -Hn); nproc=$(ulimit -Hu)
  [ "$nofile" = unlimited ] || [ "$nofile" -gt 1024 ] && nofile=1024
  [ "$nproc" = unlimited ] || [ "$nproc" -gt 1024 ] && nproc=1024
  cat >"$CONTAINERS_CONF" <<CONF
# Written by deploy/podman.sh; every podman call (podman-compose's too) reads it via CONTAINERS_CONF.
[containers]
default_ulimits = ["nofile=$nofile:$nofile", "nproc=$nproc:$nproc"]

[engine]
runtime = "runc"
CONF
  podman info >/dev/null 2>&1 || fail "podman is installed but does not run: $(podman info 2>&1 | tail -1)"
  say "podman $(podman version --format '{{.Client.Version}}'), podman-compose $PODMAN_COMPOSE_VERSION, $CONTAINERS_CONF"
}

debian_mirror() {
  # The machine's own Debian mirror, from apt's sources (deb822 first, then the one-line format).
  local uri=""
  if [ -f /etc/apt/sources.list.d/debian.sources ]; then
    uri=$(awk '$1 == "URIs:" { print $2; exit }' /etc/apt/sources.list.d/debian.sources)
  fi
  if [ -z "$uri" ] && [ -f /etc/apt/sources.list ]; then
    uri=$(awk '$1 == "deb" && $2 !~ /security/ { print $2; exit }' /etc/apt/sources.list)
  fi
  [ -n "$uri" ] || fail "no Debian mirror in /etc/apt/sources.list.d/debian.sources or /etc/apt/sources.list"
  printf '%s\n' "$uri"
}

make_base() {
  # The official image cannot be pulled: an equivalent made from Debian's packages (python3 in a
  # venv at /usr/local, so `python` and `pip` on PATH install there as in the official image).
  [ "$(id -u)" = 0 ] || fail "making the base image $BASE needs root (debootstrap, chroot); pull it instead"
  command -v debootstrap >/dev/null || fail "debootstrap is missing (deploy/podman.sh engine installs it)"
  local mirror suite rootfs
  mirror=$(debian_mirror)
  suite=$(. /etc/os-release && printf '%s' "${VERSION_CODENAME:-bookworm}")
  rootfs=$(mktemp -d "${TMPDIR:-/tmp}/formation-rootfs.XXXXXX")
  # shellcheck disable=SC2064
  trap "umount '$rootfs/proc' 2>/dev/null || true; rm -rf '$rootfs'" RETURN
  say "debootstrap $suite (minbase) from the machine's Debian mirror"
  debootstrap --variant=minbase "$suite" "$rootfs" "$mirror" >"$rootfs.log" 2>&1 ||
    { tail -20 "$rootfs.log" >&2; fail "debootstrap failed"; }
  rm -f "$rootfs.log"
  if [ -f /etc/apt/sources.list.d/debian.sources ]; then
    cp /etc/apt/sources.list.d/debian.sources "$rootfs/etc/apt/sources.list.d/debian.sources"
  fi
  cp /etc/resolv.conf "$rootfs/etc/resolv.conf"
  mount -t proc proc "$rootfs/proc"
  chroot "$rootfs" sh -c 'apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends python3 python3-venv ca-certificates >/dev/null && apt-get clean && rm -rf /var/lib/apt/lists/*' ||
    fail "apt-get in the base image's rootfs failed"
  chroot "$rootfs" python3 -m venv /usr/local
  umount "$rootfs/proc"
  # pip's TLS here needs the machine's CA bundle.
  [ -f /etc/ssl/certs/ca-certificates.crt ] && cp /etc/ssl/certs/ca-certificates.crt "$rootfs/etc/ssl/certs/ca-certificates.crt"
  : >"$rootfs/etc/resolv.conf"
  local local_name="localhost/${BASE#*/}"
  [[ $BASE == */* ]] || local_name="localhost/$BASE"
  tar -C "$rootfs" -c . | podman import --quiet \
    --change 'ENV PATH=/usr/local/bin:/usr/local/sbin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' --change 'CMD ["python3"]' - "$local_name" >/dev/null
  # Tagged with the FROM name, so the unchanged Dockerfile resolves it with --pull=never.
  local full=$BASE
  [[ $BASE == */* ]] || full="docker.io/library/$BASE"
  podman tag "$local_name" "$full"
}

base() {
  local t0; t0=$(now)
  if podman image exists "$BASE"; then
    say "base image $BASE: cached"
  elif timeout 60 podman pull -q "$BASE" >/dev/null 2>&1; then
    say "base image $BASE: pulled in $(took "$t0") s"
  else
    say "base image $BASE: no registry serves it; making it locally"
    make_base
    say "base image $BASE: made in $(took "$t0") s"
  fi
}

build() {
  local t0; t0=$(now)
  # shellcheck disable=SC2086
  podman build --pull=never -q ${FORMATION_BUILD_FLAGS:-} -t "$IMAGE" . >/dev/null ||
    fail "podman build of $IMAGE failed"
  say "image $IMAGE built in $(took "$t0") s, $(podman image inspect "$IMAGE" --format '{{.Size}}' | awk '{ printf "%.0f MB", $1 / 1e6 }')"
}

env_vars() {
  printf 'CONTAINERS_CONF=%s\nPODMAN_COMPOSE=%s\nFORMATION_IMAGE=%s\n' \
    "$CONTAINERS_CONF" "$COMPOSE_VENV/bin/podman-compose" "$IMAGE"
}

[ $# -gt 0 ] || { sed -n '2,11p' "$0"; exit 2; }
for step in "$@"; do
  case $step in
    engine) engine ;;
    base) base ;;
    build) build ;;
    env) env_vars ;;
    *) fail "unknown step '$step' (engine, base, build, env)" ;;
  esac
done
