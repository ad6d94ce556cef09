#!/usr/bin/env bash
# Runs a command of this repository inside a brand-new minimal Debian 12 root,
# as a new user's machine would be: nothing installed but Debian's minbase.
#
# Usage: scripts/fresh-machine.sh [--keep] [COMMAND [ARGS...]]   (default: scripts/test.sh)
#   e.g. scripts/fresh-machine.sh scripts/test.sh
#        scripts/fresh-machine.sh scripts/run.sh --headless-check
#
# The pristine root (debootstrap --variant=minbase bookworm, about 3 minutes) is
# made once and kept as a tarball in $PENUMBRA_FRESH_CACHE (default
# /var/cache/penumbra-fresh-machine), outside the clone. Only that pristine root
# is cached: every run unpacks it into a new folder, copies the clone (its
# committed and uncommitted files, no build trees) and ../shared into it, and runs
# COMMAND there as root in a chroot of its own mount namespace, with /proc, /sys
# and /dev mounted so that the network-namespace tests run. The folder is
# deleted afterwards (--keep leaves it, and says where). Inside, the
# multi-host tests fail rather than skip when network namespaces cannot be
# made (PENUMBRA_REQUIRE_NETNS=1): this root is root's, with /proc, /sys, /dev.
# The Debian mirror is the one this machine's apt sources name; nothing about it
# is written into the repository. Needs root, debootstrap and unshare.
set -euo pipefail
export PATH="/usr/local/sbin:/usr/sbin:/sbin:$PATH"  # debootstrap, chroot: root's tools, wherever PATH was cut
root="$(cd "$(dirname "$0")/.." && pwd)"
cache="${PENUMBRA_FRESH_CACHE:-/var/cache/penumbra-fresh-machine}"
keep=0
case "${1:-}" in
  -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
  --keep) keep=1; shift ;;
esac
if [ $# -eq 0 ]; then set -- scripts/test.sh; fi

say() { echo "fresh-machine: $*"; }
die() { echo "fresh-machine: $*" >&2; exit 1; }
elapsed() { echo $(( $(date +%s) - $1 ))s; }

[ "$(id -u)" -eq 0 ] || die "needs root (chroot, mounts, debootstrap)"
command -v unshare >/dev/null || die "unshare (util-linux) is missing"
if ! command -v debootstrap >/dev/null; then
  say "installing debootstrap"
  DEBIAN_FRONTEND=noninteractive apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends debootstrap >/dev/null
fi

# The first Debian mirror in this machine's apt sources that serves bookworm
# (deb822 .sources files or one-line sources.list), never a security mirror.
debian_mirror() {
  local f
  for f in /etc/apt/sources.list.d/*.sources; do
    [ -f "$f" ] || continue
    awk 'BEGIN{RS=""} /Suites:[^\n]*bookworm( |$|\n)/ && !/security/ {
           if (match($0, /URIs:[ \t]*[^ \t\n]+/)) { s = substr($0, RSTART, RLENGTH); sub(/URIs:[ \t]*/, "", s); print s; exit } }' "$f"
  done
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list; do
    [ -f "$f" ] || continue
    awk '$1 == "deb" && $0 !~ /security/ { for (i = 2; i <= NF; i++) if ($i ~ /^[a-z]+:\/\//) { if ($(i+1) == "bookworm") { print $i; exit } } }' "$f"
  done
}

pristine="$cache/bookworm-minbase.tar"
t_all=$(date +%s)
if [ ! -s "$pristine" ]; then
  mirror="$(debian_mirror | head -n 1)"
  [ -n "$mirror" ] || die "no Debian bookworm mirror found in /etc/apt/sources.list{,.d/*}"
  say "making the pristine Debian 12 minbase root from $mirror (once; cached in $cache)"
  t=$(date +%s)
  mkdir -p "$cache"
  staging="$(mktemp -d "$cache/debootstrap-XXXXXX")"
  if ! debootstrap --variant=minbase bookworm "$staging/root" "$mirror" >"$cache/debootstrap.log" 2>&1; then
    tail -n 20 "$cache/debootstrap.log" >&2
    rm -rf "$staging"
    die "debootstrap failed; full log in $cache/debootstrap.log"
  fi
  tar -C "$staging/root" -cf "$pristine.tmp" .
  mv "$pristine.tmp" "$pristine"   # atomic: a half-written tarball is never taken for the root
  rm -rf "$staging"
  say "root created in $(elapsed "$t")"
else
  say "root: cache hit ($pristine)"
fi

work="$(mktemp -d /var/tmp/penumbra-fresh-XXXXXX)"
cleanup() {
  if [ "$keep" -eq 1 ]; then say "kept the root in $work/root"; else rm -rf "$work"; fi
}
trap cleanup EXIT
t=$(date +%s)
mkdir "$work/root"
tar -C "$work/root" -xf "$pristine"

# The clone and ../shared, at the same relative places as here.
name="$(basename "$root")"
dest="$work/root/work/$name"
mkdir -p "$dest"
if git -C "$root" rev-parse --git-dir >/dev/null 2>&1; then
  # Tracked and untracked-but-not-ignored files: what a clone plus the change holds.
  git -C "$root" ls-files -z --cached --others --exclude-standard |
    (cd "$root" && xargs -0 -r cp --parents -a -t "$dest" 2>/dev/null || true)
  cp -a "$root/.git" "$dest/.git"
else
  cp -a "$root/." "$dest/"
  rm -rf "$dest"/build*
fi
if [ -d "$root/../shared" ]; then
  mkdir "$work/root/work/shared"
  cp -a "$root/../shared/." "$work/root/work/shared/"   # its contents, even when ../shared is a symlink
  chmod -R a-w "$work/root/work/shared"   # as CI lays it: read-only
else
  say "no ../shared beside the clone; tests that need it will skip"
fi
# What an installed machine has besides its packages, and debootstrap does not
# write: a resolver configuration and a hosts file (`ip netns exec` binds a
# namespace's hosts file over /etc/hosts, which must exist).
cp /etc/resolv.conf "$work/root/etc/resolv.conf"
# ... and the network's own trust anchors: where TLS to the package
# registries passes through a proxy with its own CA, a machine on that
# network has the CA installed locally (ca-certificates' postinst, run by
# install-deps, adds them to the system store) and the trust variables set
# (Node.js reads NODE_EXTRA_CA_CERTS, not the system store).
if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
  mkdir -p "$work/root/usr/local/share/ca-certificates"
  cp /usr/local/share/ca-certificates/*.crt "$work/root/usr/local/share/ca-certificates/"
fi
trust_env=()
for var in NODE_EXTRA_CA_CERTS SSL_CERT_FILE; do
  if [ -n "${!var:-}" ]; then trust_env+=("$var=${!var}"); fi
done
[ -e "$work/root/etc/hosts" ] || printf '127.0.0.1\tlocalhost\n::1\t\tlocalhost ip6-localhost ip6-loopback\n' >"$work/root/etc/hosts"
say "root laid out in $(elapsed "$t"); running '$*' in /work/$name"

# A mount namespace of our own: every mount below vanishes with it, whatever happens.
status=0
export PENUMBRA_TRUST_ENV="${trust_env[*]:-}"
unshare --mount --propagation private -- bash -euo pipefail -c '
  r="$1"; name="$2"; shift 2
  # The root a mount point of its own, as on a real machine: `ip netns exec`
  # remounts / (make-rslave), which fails on a plain directory.
  mount --bind "$r" "$r"
  mount -t proc proc "$r/proc"
  mount -t sysfs sysfs "$r/sys"
  mount --rbind /dev "$r/dev"
  mount -t tmpfs tmpfs "$r/tmp"
  mount -t tmpfs tmpfs "$r/run"
  mkdir -p "$r/dev/shm"
  exec chroot "$r" /usr/bin/env -i HOME=/root TERM="${TERM:-dumb}" LANG=C.UTF-8 \
    PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin CI="${CI:-}" \
    PENUMBRA_REQUIRE_NETNS=1 $PENUMBRA_TRUST_ENV \
    bash -c "cd /work/$name && exec \"\$@\"" fresh-machine "$@"
' fresh-machine "$work/root" "$name" "$@" || status=$?
say "'$*' exited $status after $(elapsed "$t") (total $(elapsed "$t_all"))"
exit "$status"
