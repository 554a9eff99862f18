# shellcheck shell=bash
# What deploy/podman.sh and deploy/docker.sh share: messages and timing, root, and the
# Dockerfile's FROM image made locally when no registry serves it. Sourced, not run.
#
# The caller sets BASE (the FROM name, e.g. python:3.12-slim) and calls
#   make_base NAME IMPORT...   # e.g. make_base localhost/python:3.12-slim podman import --quiet
# which builds the rootfs and pipes it to `IMPORT --change ... - NAME`. No host name is
# written here: the Debian mirror is read from apt's sources.

say() { printf '%s: %s\n' "${0##*/}" "$*" >&2; }
fail() { say "error: $*"; exit 1; }
now() { date +%s.%N; }
took() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo "$@"
  else return 1
  fi
}

# apt_install WHAT HINT MISSING PACKAGE...: install PACKAGEs as root for the tools MISSING
# (space-separated) names; every failure says WHAT is not there, and HINT without apt-get.
apt_install() {
  local what=$1 hint=$2 missing=$3; shift 3
  command -v apt-get >/dev/null ||
    fail "$what: $missing missing and no apt-get to install them; $hint"
  say "installing $* for $missing (apt-get)"
  as_root apt-get update -qq || fail "$what: cannot run apt-get as root to install $*"
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null ||
    fail "$what: apt-get could not install $*"
}

# The machine's hard limits for open files and processes, capped at 1024: the engines'
# defaults are above the hard limits here ("setrlimit RLIMIT_NOFILE: Operation not permitted").
ulimit_nofile() { local n; n=$(ulimit -Hn); { [ "$n" = unlimited ] || [ "$n" -gt 1024 ]; } && n=1024; printf '%s\n' "$n"; }
ulimit_nproc() { local n; n=$(ulimit -Hu); { [ "$n" = unlimited ] || [ "$n" -gt 1024 ]; } && n=1024; printf '%s\n' "$n"; }

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
  # Arguments: NAME IMPORT... ; the rootfs goes to `IMPORT --change ... - NAME` as a tar stream.
  local name=$1; shift
  [ "$(id -u)" = 0 ] || fail "making the base image $BASE needs root (debootstrap, chroot); pull it instead"
  command -v debootstrap >/dev/null || fail "debootstrap is missing (the engine step installs it)"
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
  tar -C "$rootfs" -c . | "$@" \
    --change 'ENV PATH=/usr/local/bin:/usr/local/sbin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' --change 'CMD ["python3"]' - "$name" >/dev/null
}
