#!/usr/bin/env bash
# Before/after for issue 13: builds penumbra-sma and penumbra-renderer of each
# git REF in a temporary worktree and runs this checkout's sma_clients_bench
# against them (the protocol and the flags the bench uses are the same on both
# sides), then prints one table with a column per REF and client count.
#
#   bench/sma_clients.sh [REF ...] [-- sma_clients_bench options]
#   bench/sma_clients.sh 7c55297 main              # before and after
#   bench/sma_clients.sh 7c55297 HEAD -- --clients 1,8,32 --poses 3
#
# REF defaults to HEAD. The REFs run one after another, in the order given
# (the machine is shared: run them back to back, and note its load). Each
# REF's worktree and build live in build/sma-clients/<commit>/ under this
# checkout, laid out as every worktree is (<dir>/build) so that ccache
# (CCACHE_BASEDIR=/work) hits what other worktrees compiled; they are kept for
# the next run (KEEP=0 removes them afterwards). Results: build/sma-clients/
# <commit>.tsv per REF and build/sma-clients/table.md for the joined table.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
refs=()
while [[ $# -gt 0 && "$1" != "--" ]]; do refs+=("$1"); shift; done
[[ "${1:-}" == "--" ]] && shift
bench_args=("$@")
[[ ${#refs[@]} -eq 0 ]] && refs=(HEAD)
keep="${KEEP:-1}"
work="$root/build/sma-clients"
mkdir -p "$work"
[[ -f /etc/profile.d/ccache-penumbra.sh ]] && source /etc/profile.d/ccache-penumbra.sh

# The bench itself, from this checkout.
[[ -f "$root/build/CMakeCache.txt" ]] || cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$root/build" -j"$(nproc)" --target sma_clients_bench >/dev/null
bench="$root/build/bench/sma_clients_bench"

commits=()
for ref in "${refs[@]}"; do
  commit="$(git -C "$root" rev-parse --verify "$ref^{commit}")"
  commits+=("$commit")
  dir="$work/$commit"
  if [[ ! -d "$dir" ]]; then
    git -C "$root" worktree add --detach "$dir" "$commit" >/dev/null
  fi
  echo "sma_clients.sh: building $ref (${commit:0:12}) in $dir/build" >&2
  t0=$(date +%s)
  cmake -S "$dir" -B "$dir/build" -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
  cmake --build "$dir/build" -j"$(nproc)" --target penumbra-sma penumbra-renderer >/dev/null
  echo "sma_clients.sh: built in $(( $(date +%s) - t0 )) s" >&2
done

for i in "${!refs[@]}"; do
  ref="${refs[$i]}"
  commit="${commits[$i]}"
  dir="$work/$commit"
  echo "sma_clients.sh: running $ref (${commit:0:12}); load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
  t0=$(date +%s)
  # The scene comes from this checkout (its ../shared): the same file for every REF.
  "$bench" --sma-exe "$dir/build/sma/penumbra-sma" --renderer-exe "$dir/build/renderer/penumbra-renderer" \
    --results "$work/$commit.tsv" "${bench_args[@]}" | tee "$work/$commit.txt"
  echo "sma_clients.sh: $ref ran in $(( $(date +%s) - t0 )) s" >&2
done

# One table: a row per figure, a column per REF and client count.
{
  printf '| |'
  for i in "${!refs[@]}"; do
    for n in $(cut -f1 "$work/${commits[$i]}.tsv" | sed 's/\..*//' | awk '!seen[$0]++'); do
      printf ' %s, %s clients |' "${refs[$i]} (${commits[$i]:0:7})" "${n#n}"
    done
  done
  printf '\n|---|'
  for i in "${!refs[@]}"; do
    for _ in $(cut -f1 "$work/${commits[$i]}.tsv" | sed 's/\..*//' | awk '!seen[$0]++'); do printf -- '---|'; done
  done
  printf '\n'
  # Keys in the bench's order, labels from the first REF's file.
  cut -f1 "$work/${commits[0]}.tsv" | sed 's/^[^.]*\.//' | awk '!seen[$0]++' | while read -r key; do
    label="$(awk -F'\t' -v k="$key" '{ split($1, p, "."); if (p[2] == k) { print $3; exit } }' "$work/${commits[0]}.tsv")"
    printf '| %s |' "$label"
    for i in "${!refs[@]}"; do
      awk -F'\t' -v k="$key" '{ split($1, p, "."); if (p[2] == k) printf " %s |", $2 }' "$work/${commits[$i]}.tsv"
    done
    printf '\n'
  done
} | tee "$work/table.md"

if [[ "$keep" == 0 ]]; then
  for commit in "${commits[@]}"; do git -C "$root" worktree remove --force "$work/$commit"; done
fi
