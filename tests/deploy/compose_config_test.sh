#!/usr/bin/env bash
# Validates deploy/docker-compose.yml without a Docker engine:
# `docker-compose config -q` with the defaults, then with every documented
# variable overridden, checking in the resolved file that each override
# reached the place it configures and that each service's Dockerfile exists.
#
# Usage: compose_config_test.sh SOURCE_DIR
# Exit 77 (skipped) only when docker-compose is not installed;
# scripts/install-deps.sh installs it.
set -euo pipefail

src="$1"
compose_file="$src/deploy/docker-compose.yml"
if ! command -v docker-compose >/dev/null 2>&1; then
  echo "SKIP: docker-compose is not installed (scripts/install-deps.sh installs it); $compose_file not validated"
  exit 77
fi

failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
work="$(mktemp -d "${TMPDIR:-/tmp}/penumbra-compose-XXXXXX")"
trap 'rm -rf "$work"' EXIT

# Variables set in the caller's environment must not leak into the defaults.
unset $(compgen -e | grep '^PENUMBRA_' || true)

if ! docker-compose -f "$compose_file" config -q 2>"$work/errors"; then
  fail "docker-compose config rejects $compose_file:"
  cat "$work/errors"
  exit 1
fi

docker-compose -f "$compose_file" config >"$work/defaults.yml"
expect() {  # expect FILE TEXT WHAT: FILE must contain the line TEXT
  grep -qxF -- "$2" "$1" || fail "$3: no line '$2' in the resolved compose file"
}
expect "$work/defaults.yml" "      replicas: 2" "default renderer replicas"
expect "$work/defaults.yml" "    scale: 2" "default renderer scale (docker-compose v1)"
expect "$work/defaults.yml" "    - --scene=/scenes/cornell-box.json" "default scene"
expect "$work/defaults.yml" "      source: $src/scenes" "default scene directory (the repository's scenes/)"
[ "$(grep -c "^    - read_only: true$" "$work/defaults.yml")" -eq 3 ] ||
  fail "the scene directory should be mounted read-only into the renderer, the SMA and the client"
expect "$work/defaults.yml" "    - --renderer=renderer:7100" "SMA finds renderers by the service's DNS name"
expect "$work/defaults.yml" "    - 127.0.0.1:7200:7200/tcp" "SMA port published on loopback only by default"
expect "$work/defaults.yml" "    - --until-converged" "client job runs until converged"
expect "$work/defaults.yml" "    - --camera-path=/scenes/cornell-box.json#walk" "client job walks the scene's path"
expect "$work/defaults.yml" "    - --connect=sma:7200" "client job connects to the SMA service"
expect "$work/defaults.yml" "    - --cache-dir=/var/lib/penumbra-sma" "SMA keeps its cache on disk"
expect "$work/defaults.yml" "    - --cache-snapshot-interval=30" "default cache snapshot interval"
expect "$work/defaults.yml" "    - sma-cache:/var/lib/penumbra-sma:rw" "SMA cache directory on a volume"
expect "$work/defaults.yml" "    - --http=0.0.0.0:7101" "renderer serves its operator HTTP endpoint"
expect "$work/defaults.yml" "    - --http=0.0.0.0:7201" "SMA serves its operator HTTP endpoint"
expect "$work/defaults.yml" "    - 127.0.0.1:7201:7201/tcp" "SMA HTTP endpoint published on loopback only by default"
# Health checks are readiness (/readyz through penumbra-stats) on each
# tier's --http port, never a look at /proc/net/tcp.
for port in 7101 7201; do
  grep -qxF -- "      - 127.0.0.1:$port" "$work/defaults.yml" ||
    fail "no health check asks /readyz on 127.0.0.1:$port"
done
[ "$(grep -c -- "^      - --ready$" "$work/defaults.yml")" -eq 2 ] ||
  fail "the renderer's and the SMA's health checks should both be 'penumbra-stats --ready'"
grep -q "/proc/net/tcp" "$work/defaults.yml" && fail "a health check still reads /proc/net/tcp"
# Each image's own HEALTHCHECK asks the --http port the compose file gives.
for tier in renderer:7101 sma:7201; do
  grep -qF "\"127.0.0.1:${tier#*:}\"]" "$src/deploy/${tier%%:*}.Dockerfile" ||
    fail "deploy/${tier%%:*}.Dockerfile's HEALTHCHECK does not ask 127.0.0.1:${tier#*:}, the --http port of the compose file"
done
expect "$work/defaults.yml" "        condition: service_healthy" "the client job waits until the SMA is ready"
[ -f "$src/scenes/cornell-box.json" ] || fail "the default scene scenes/cornell-box.json is missing"

PENUMBRA_RENDERERS=5 PENUMBRA_SCENE=sponza.json PENUMBRA_SCENES_DIR=/srv/scenes PENUMBRA_SPP=256 \
  PENUMBRA_RENDERER_THREADS=3 PENUMBRA_SMA_PORT=9200 PENUMBRA_SMA_BIND=0.0.0.0 PENUMBRA_RESOLVE_INTERVAL=2 \
  PENUMBRA_SMA_HTTP_PORT=9201 PENUMBRA_CAMERA_PATH=orbit PENUMBRA_CLIENT_TIMEOUT=60 PENUMBRA_LOG_LEVEL=debug PENUMBRA_TAG=v9 \
  PENUMBRA_CACHE_SNAPSHOT_INTERVAL=120 \
  docker-compose -f "$compose_file" config >"$work/overridden.yml"
expect "$work/overridden.yml" "      replicas: 5" "PENUMBRA_RENDERERS"
expect "$work/overridden.yml" "    scale: 5" "PENUMBRA_RENDERERS (scale)"
expect "$work/overridden.yml" "    - --scene=/scenes/sponza.json" "PENUMBRA_SCENE"
expect "$work/overridden.yml" "      source: /srv/scenes" "PENUMBRA_SCENES_DIR"
expect "$work/overridden.yml" "    - --spp=256" "PENUMBRA_SPP"
expect "$work/overridden.yml" "    - --threads=3" "PENUMBRA_RENDERER_THREADS"
expect "$work/overridden.yml" "    - 0.0.0.0:9200:7200/tcp" "PENUMBRA_SMA_BIND and PENUMBRA_SMA_PORT"
expect "$work/overridden.yml" "    - 0.0.0.0:9201:7201/tcp" "PENUMBRA_SMA_BIND and PENUMBRA_SMA_HTTP_PORT"
expect "$work/overridden.yml" "    - --resolve-interval=2" "PENUMBRA_RESOLVE_INTERVAL"
expect "$work/overridden.yml" "    - --camera-path=/scenes/sponza.json#orbit" "PENUMBRA_CAMERA_PATH"
expect "$work/overridden.yml" "    - --timeout=60" "PENUMBRA_CLIENT_TIMEOUT"
expect "$work/overridden.yml" "    - --log-level=debug" "PENUMBRA_LOG_LEVEL"
expect "$work/overridden.yml" "    image: penumbra-renderer:v9" "PENUMBRA_TAG"
expect "$work/overridden.yml" "    - --cache-snapshot-interval=120" "PENUMBRA_CACHE_SNAPSHOT_INTERVAL"

# Every service builds from a Dockerfile that exists, with the repository as
# its context.
while read -r dockerfile; do
  [ -f "$src/$dockerfile" ] || fail "a service builds from $dockerfile, which does not exist"
done < <(awk '$1 == "dockerfile:" {print $2}' "$work/defaults.yml")
[ "$(grep -c "^      context: $src\$" "$work/defaults.yml")" -eq 3 ] ||
  fail "every service should build with the repository root as context"

if [ "$failures" -ne 0 ]; then
  echo "$failures problem(s) in $compose_file"
  exit 1
fi
echo "OK: $compose_file validates; defaults and overrides resolve as documented"
