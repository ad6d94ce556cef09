#!/usr/bin/env bash
# Validates deploy/k8s/ without a cluster:
#  1. yamllint (deploy/k8s/.yamllint) on every YAML file there and on
#     deploy/docker-compose.yml;
#  2. every manifest against the Kubernetes API schemas (kubernetes-models,
#     from deploy/k8s/validate's package-lock.json, installed with `npm ci`
#     into WORK_DIR), unknown fields included (validate.mjs);
#  3. the manifests and the compose file agree: images, flags, ports, memory
#     limits, health endpoints, renderer discovery, autoscaling
#     (consistency.mjs).
#
# Usage: k8s_manifests_test.sh SOURCE_DIR WORK_DIR
# Exit 77 (skipped) only when node, npm, yamllint or docker-compose is not
# installed; scripts/install-deps.sh installs them.
set -euo pipefail

src="$1"
work="$2"
k8s="$src/deploy/k8s"
for tool in node npm yamllint docker-compose; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "SKIP: $tool is not installed (scripts/install-deps.sh installs it); $k8s not validated"
    exit 77
  fi
done

failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# --- 1. YAML style --------------------------------------------------------
mapfile -t yaml_files < <(find "$k8s" -name node_modules -prune -o -name '*.yaml' -print | sort)
[ "${#yaml_files[@]}" -ge 4 ] || fail "expected the manifests in $k8s, found ${#yaml_files[@]} YAML file(s)"
if ! yamllint -s -c "$k8s/.yamllint" "${yaml_files[@]}" "$src/deploy/docker-compose.yml"; then
  fail "yamllint"
fi

# --- 2. Kubernetes schemas ------------------------------------------------
# npm ci only when the lock file changed since the last install here.
modules_dir="$work/k8s-validate"
mkdir -p "$modules_dir"
if ! cmp -s "$k8s/validate/package-lock.json" "$modules_dir/installed-package-lock.json" ||
   [ ! -d "$modules_dir/node_modules" ]; then
  cp "$k8s/validate/package.json" "$k8s/validate/package-lock.json" "$modules_dir/"
  if ! (cd "$modules_dir" && npm ci --no-audit --no-fund --loglevel=error) >"$modules_dir/npm.log" 2>&1; then
    cat "$modules_dir/npm.log"
    echo "FAIL: npm ci in $modules_dir"
    exit 1
  fi
  cp "$k8s/validate/package-lock.json" "$modules_dir/installed-package-lock.json"
fi
export PENUMBRA_K8S_NODE_MODULES="$modules_dir/node_modules"
mapfile -t manifests < <(find "$k8s" -maxdepth 1 -name '*.yaml' | sort)
node "$k8s/validate/validate.mjs" "${manifests[@]}" || fail "manifests do not validate"

# --- 3. consistent with the compose file ----------------------------------
resolved="$(mktemp "${TMPDIR:-/tmp}/penumbra-k8s-compose-XXXXXX.yml")"
trap 'rm -f "$resolved"' EXIT
(unset $(compgen -e | grep '^PENUMBRA_' || true); docker-compose -f "$src/deploy/docker-compose.yml" config) >"$resolved"
node "$k8s/validate/consistency.mjs" "$resolved" "$k8s" || fail "deploy/k8s and deploy/docker-compose.yml disagree"

if [ "$failures" -ne 0 ]; then
  echo "$failures problem(s) in $k8s"
  exit 1
fi
echo "OK: $k8s: ${#manifests[@]} manifest file(s) valid, consistent with deploy/docker-compose.yml"
