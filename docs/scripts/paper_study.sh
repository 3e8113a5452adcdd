#!/usr/bin/env bash
# Reruns the paper-protocol study of docs/results.md (*The paper's protocol*) and prints its
# tables: for each scene, pipelines/paper_<scene>.ron — three optimiser seeds, 3DGS, Staged
# and Dual, each at its best checkpoint — and the ensemble's own quality.
#
#   bash docs/scripts/paper_study.sh [--improved] [SCENE…] [-- AUGSPLAT-RUN-ARGS…]
#
# SCENE: generated dtu_scan24 bonsai fern horns (the default: all five). --improved adds
# pipelines/fragments/improved_dual.ron (our improved Dual; only Dual and its evaluation
# rerun). Arguments after `--` go to `augsplat run` (e.g. `--set baseline.densify.reset=Never`).
#
# The whole study takes hours on a 2-core machine (docs/results.md gives the times); each
# scene's fields, renders and ensemble are shared by its three seeds and by every preset, and
# everything is cached, so a rerun or a second preset pays only for what changed. Needs
# ../shared/data beside the repository and a release build (cargo build --release).
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/paper[_improved]/<scene>/ (the
# evaluations, via --out), <scene>.summary.json (each node's compute seconds) and <scene>.log;
# the Markdown tables on stdout (docs/scripts/paper_table.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
preset=paper
scenes=()
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --improved) preset=paper_improved; shift ;;
    --) shift; extra=("$@"); break ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) scenes+=("$1"); shift ;;
  esac
done
[ ${#scenes[@]} -gt 0 ] || scenes=(generated dtu_scan24 bonsai fern horns)
out="$root/docs/scripts/out/$preset"
mkdir -p "$out"
targets=(--target eval_baseline --target eval_staged --target eval_dual --target eval_ensemble)
for s in "${scenes[@]}"; do
  [ -f "$root/pipelines/paper_$s.ron" ] || { echo "no pipelines/paper_$s.ron" >&2; exit 2; }
  p="$root/pipelines/paper_$s.ron"
  if [ "$preset" = paper_improved ]; then
    p="$out/paper_${s}_improved.ron"
    printf '(extends: ["%s/pipelines/paper_%s.ron", "%s/pipelines/fragments/improved_dual.ron"])\n' \
      "$root" "$s" "$root" >"$p"
  fi
  echo "== $s ($preset) $(date -u +%FT%TZ)" >&2
  rm -rf "${out:?}/$s"
  "$bin" run "$p" -q --log "${targets[@]}" ${extra[@]+"${extra[@]}"} --out "$out/$s" \
    --summary-json "$out/$s.summary.json" >"$out/$s.log" 2>&1 \
    || { echo "run of $s failed: see $out/$s.log" >&2; exit 1; }
done
python3 "$root/docs/scripts/paper_table.py" "$out" "${scenes[@]}"
