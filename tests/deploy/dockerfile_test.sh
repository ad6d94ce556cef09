#!/usr/bin/env bash
# Checks a deploy/*.Dockerfile without a Docker engine, against the files it
# mirrors:
#  1. its shape: a `debian:12 AS build` stage and a `debian:12-slim` runtime
#     stage, a non-root USER, ENTRYPOINT in exec form naming the executable the
#     build stage builds and copies, unless --no-healthcheck a HEALTHCHECK
#     that asks `penumbra-stats --ready` (copied into the image, built by the
#     build stage) for /readyz on an EXPOSEd port other than the first (the
#     tier's --http port);
#  2. every package the build stage installs is one scripts/install-deps.sh
#     installs (so the image builds with what the project is tested with);
#  3. the build context that /.dockerignore lets through is enough: the build
#     stage's own cmake configure command, run on a copy of that context,
#     succeeds and knows the target the stage builds;
#  4. every shared library that ldd lists for the executable built here comes
#     from a package of the runtime stage, from one of their dependencies, or
#     from the base image (Essential / Priority required and their
#     dependencies) -- i.e. the runtime stage misses no library; the same
#     for penumbra-stats when the image has the health check.
#
# Usage: dockerfile_test.sh SOURCE_DIR DOCKERFILE EXECUTABLE (--no-healthcheck | --stats STATS_EXECUTABLE)
set -euo pipefail

src="$1"
dockerfile="$2"
exe="$3"
want_healthcheck=1
stats_exe=""
case "${4:-}" in
  --no-healthcheck) want_healthcheck=0 ;;
  --stats) stats_exe="${5:?--stats needs the penumbra-stats executable}" ;;
  *) echo "usage: $0 SOURCE_DIR DOCKERFILE EXECUTABLE (--no-healthcheck | --stats STATS_EXECUTABLE)" >&2; exit 2 ;;
esac

name="$(basename "$dockerfile")"
failures=0
fail() { echo "FAIL $name: $*"; failures=$((failures + 1)); }
work="$(mktemp -d "${TMPDIR:-/tmp}/penumbra-dockerfile-XXXXXX")"
trap 'rm -rf "$work"' EXIT

# Instructions, one per line: continuations joined, comments dropped.
sed -e '/^[[:space:]]*#/d' "$dockerfile" | sed -e ':a' -e '/\\$/N; s/\\\n//; ta' |
  sed -e '/^[[:space:]]*$/d' >"$work/instructions"

# --- 1. shape -------------------------------------------------------------
mapfile -t froms < <(grep -E '^FROM ' "$work/instructions")
if [ "${#froms[@]}" -ne 2 ]; then
  fail "expected 2 stages (build, runtime), found ${#froms[@]}"
else
  [[ "${froms[0]}" =~ ^FROM\ debian:12\ AS\ build$ ]] || fail "first stage is '${froms[0]}', not 'FROM debian:12 AS build'"
  [[ "${froms[1]}" =~ ^FROM\ debian:12-slim$ ]] || fail "runtime stage is '${froms[1]}', not 'FROM debian:12-slim'"
fi
while read -r keyword _; do
  case "$keyword" in
    FROM|RUN|COPY|WORKDIR|USER|EXPOSE|HEALTHCHECK|ENTRYPOINT|CMD|ENV|ARG|LABEL) ;;
    *) fail "unknown or unexpected instruction '$keyword'" ;;
  esac
done <"$work/instructions"
# The runtime stage: everything after the second FROM.
awk '/^FROM /{n++} n==2' "$work/instructions" >"$work/runtime"
awk '/^FROM /{n++} n==1' "$work/instructions" >"$work/build"

user="$(grep -E '^USER ' "$work/runtime" | tail -n 1 | awk '{print $2}')"
[ -n "$user" ] || fail "runtime stage sets no USER (it would run as root)"
case "$user" in root|0|0:*|root:*) fail "runtime stage runs as $user" ;; esac

target="$(grep -oE -- '--target [A-Za-z0-9_.-]+' "$work/build" | awk '{print $2}' | tail -n 1)"
[ -n "$target" ] || fail "build stage builds no explicit --target"
[ "$target" = "$(basename "$exe")" ] || fail "builds '$target' but the tier's executable is $(basename "$exe")"
entrypoint="$(grep -E '^ENTRYPOINT ' "$work/runtime" | sed -e 's/^ENTRYPOINT //')"
[ "$entrypoint" = "[\"$target\"]" ] || fail "ENTRYPOINT is '$entrypoint', expected exec form [\"$target\"]"
grep -qE "^COPY --from=build /src/build/[a-z]+/$target /usr/local/bin/$target\$" "$work/runtime" ||
  fail "runtime stage does not COPY --from=build the built $target to /usr/local/bin"
if [ "$want_healthcheck" -eq 1 ]; then
  healthcheck="$(grep -E '^HEALTHCHECK ' "$work/runtime" || true)"
  [[ "$healthcheck" == *" CMD ["* ]] || fail "no HEALTHCHECK in exec form"
  # The health check is readiness (/readyz) through the project's own client.
  read -r -a exposed <<<"$(grep -E '^EXPOSE ' "$work/runtime" | sed -e 's/^EXPOSE //' | head -n 1)"
  if [ "${#exposed[@]}" -lt 2 ]; then
    fail "runtime stage EXPOSEs '${exposed[*]:-}': expected the tier's port, then its --http port"
  else
    http_port="${exposed[1]}"
    [[ "$healthcheck" =~ CMD\ \[\"penumbra-stats\",\ \"--ready\",.*\"127\.0\.0\.1:$http_port\"\]$ ]] ||
      fail "HEALTHCHECK is not penumbra-stats --ready on 127.0.0.1:$http_port (the EXPOSEd --http port): $healthcheck"
    if grep -qE '^CMD ' "$work/runtime"; then  # a default command must serve that port
      grep -E '^CMD ' "$work/runtime" | grep -qF "\"--http\", \"0.0.0.0:$http_port\"" ||
        fail "the default CMD does not pass --http 0.0.0.0:$http_port, which the HEALTHCHECK asks"
    fi
  fi
  grep -qE '^RUN cmake --build .*--target .*penumbra-stats' "$work/build" || fail "build stage does not build penumbra-stats"
  grep -qxF 'COPY --from=build /src/build/common/tools/penumbra-stats /usr/local/bin/penumbra-stats' "$work/runtime" ||
    fail "runtime stage does not COPY penumbra-stats (its health check client) to /usr/local/bin"
fi

# apt-get install package lists of a stage.
apt_packages() {
  grep -E '^RUN .*apt-get install' "$1" | sed -e 's/.*apt-get install//' -e 's/&&.*//' |
    tr ' ' '\n' | grep -vE '^(-|$)' | sort -u
}

# --- 2. build packages come from install-deps.sh --------------------------
sed -n '/^packages=(/,/^)/p' "$src/scripts/install-deps.sh" | sed -e 's/#.*//' -e 's/packages=(//' -e 's/)//' |
  tr ' ' '\n' | sed -e '/^$/d' | sort -u >"$work/install-deps"
[ -s "$work/install-deps" ] || fail "could not read the package list of scripts/install-deps.sh"
apt_packages "$work/build" >"$work/build-packages"
[ -s "$work/build-packages" ] || fail "build stage installs no packages"
while read -r p; do
  grep -qxF "$p" "$work/install-deps" || fail "build stage installs $p, which scripts/install-deps.sh does not"
done <"$work/build-packages"

# --- 3. the context /.dockerignore lets through configures ----------------
# /.dockerignore is an allowlist ("*", then "!path" lines): copy those paths.
ignore="$src/.dockerignore"
if [ "$(grep -vE '^[[:space:]]*(#|$)' "$ignore" | head -n 1)" != "*" ]; then
  fail "/.dockerignore does not start with '*' (this test reads it as an allowlist)"
else
  mkdir -p "$work/context"
  while read -r keep; do
    keep="${keep#!}"
    keep="${keep%/}"
    [ -e "$src/$keep" ] || { fail "/.dockerignore lets through $keep, which does not exist"; continue; }
    cp -a "$src/$keep" "$work/context/$keep"
  done < <(grep -E '^!' "$ignore")
  configure="$(grep -E '^RUN cmake -S ' "$work/build" | sed -e 's/^RUN //')"
  if [ -z "$configure" ]; then
    fail "build stage has no 'RUN cmake -S ...' configure step"
  elif ! (cd "$work/context" && bash -c "$configure") >"$work/configure.log" 2>&1; then
    fail "the build stage's configure step fails on the context /.dockerignore lets through:"
    tail -n 30 "$work/configure.log"
  elif ! cmake --build "$work/context/build" --target help >"$work/targets" ||
       ! grep -qE "^\.\.\. $target( |\$)" "$work/targets"; then
    fail "the configured context has no target $target"
  elif [ -n "$stats_exe" ] && ! grep -qE "^\.\.\. penumbra-stats( |\$)" "$work/targets"; then
    fail "the configured context has no target penumbra-stats"
  fi
fi

# --- 4. the runtime stage has every library the executable links ---------
apt_packages "$work/runtime" >"$work/runtime-packages"
[ -s "$work/runtime-packages" ] || fail "runtime stage installs no packages"
# Installed packages: name, essential, priority, then their dependencies
# (first alternative of each, version and architecture qualifiers dropped).
dpkg-query -W -f='${Package}\t${Essential}\t${Priority}\t${Pre-Depends}, ${Depends}\n' >"$work/dpkg"
awk -F'\t' '$2 == "yes" || $3 == "required" {print $1}' "$work/dpkg" >"$work/roots"
cat "$work/runtime-packages" >>"$work/roots"
awk -F'\t' '
  NR == FNR {
    n = split($4, deps, ",")
    for (i = 1; i <= n; i++) {
      d = deps[i]; sub(/\|.*/, "", d); sub(/\(.*/, "", d); sub(/:.*/, "", d); gsub(/[[:space:]]/, "", d)
      if (d != "") children[$1] = children[$1] " " d
    }
    next
  }
  { queue[++tail] = $1 }
  END {
    while (head < tail) {
      p = queue[++head]
      if (p in seen) continue
      seen[p] = 1; print p
      m = split(children[p], c, " ")
      for (j = 1; j <= m; j++) if (!(c[j] in seen)) queue[++tail] = c[j]
    }
  }' "$work/dpkg" "$work/roots" | sort -u >"$work/available"

for e in "$exe" $stats_exe; do
  ldd "$e" | awk '$2 == "=>" && $3 ~ /^\// {print $3}'
done | sort -u >"$work/libs"
[ -s "$work/libs" ] || fail "ldd lists no shared library for $exe"
# dpkg knows a library by the path its package ships: under /lib or /usr/lib
# (merged /usr), through a symlink or not. Ask for every spelling at once.
while read -r lib; do
  real="$(realpath "$lib")"
  printf '%s\t%s\n' "$lib" "$lib" "$lib" "$real" "$lib" "${real#/usr}" "$lib" "/usr$lib"
done <"$work/libs" >"$work/spellings"
cut -f2 "$work/spellings" | sort -u | xargs dpkg -S 2>/dev/null |
  sed -e 's/^\([^:,]*\)[^ ]* \(.*\)$/\2\t\1/' >"$work/owners" || true
while read -r lib; do
  package="$(awk -F'\t' -v lib="$lib" 'NR == FNR {owner[$1] = $2; next}
                                        $1 == lib && ($2 in owner) {print owner[$2]; exit}' \
    "$work/owners" "$work/spellings")"
  if [ -z "$package" ]; then
    fail "no Debian package owns $lib (linked by $(basename "$exe"))"
  elif ! grep -qxF "$package" "$work/available"; then
    fail "$(basename "$exe") links $lib from $package, which the runtime stage does not install"
  fi
done <"$work/libs"

if [ "$failures" -ne 0 ]; then
  echo "$name: $failures problem(s)"
  exit 1
fi
echo "$name: OK ($(wc -l <"$work/build-packages") build packages from install-deps.sh; context configures;" \
  "$(wc -l <"$work/libs") libraries of $target covered by $(wc -l <"$work/runtime-packages") runtime packages)"
