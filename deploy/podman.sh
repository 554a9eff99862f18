#!/usr/bin/env bash
# Podman for the compose test: the engine, podman-compose, the base image and the testbed's image.
#
#   deploy/podman.sh engine   # podman, runc, catatonit (+ debootstrap) from the distribution, podman-compose
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

# shellcheck source=deploy/base-image.sh
. deploy/base-image.sh

engine() {
  local missing=()
  for tool in podman runc; do command -v "$tool" >/dev/null || missing+=("$tool"); done
  # `init: true` runs podman's init, catatonit. Debian's podman only recommends it, or tini
  # instead, which docker.io brings: with both engines installed, catatonit may be missing
  # ("container-init binary not found on the host: stat /usr/libexec/podman/catatonit").
  [ -x /usr/libexec/podman/catatonit ] || missing+=(catatonit)
  if [ "$(id -u)" = 0 ] && ! command -v debootstrap >/dev/null; then missing+=(debootstrap); fi
  [ ${#missing[@]} -eq 0 ] || apt_install "no container engine" \
    "install podman and runc, or run the compose test under Docker (README, Deployment)" \
    "${missing[*]}" podman runc catatonit debootstrap
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
  nofile=$(ulimit_nofile); nproc=$(ulimit_nproc)
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

make_podman_base() {
  local local_name="localhost/${BASE#*/}"
  [[ $BASE == */* ]] || local_name="localhost/$BASE"
  make_base "$local_name" podman import --quiet
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
    make_podman_base
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
