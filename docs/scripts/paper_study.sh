#!/usr/bin/env bash
# Reruns the paper-protocol study of docs/results.md (*The paper's protocol*) and prints its
# tables: for each scene, pipelines/paper_<scene>.ron — three optimiser seeds, 3DGS, Staged
# and Dual, each at its best checkpoint — and the ensemble's own quality.
#
#   bash docs/scripts/paper_study.sh [--improved] [--fragment NAME]… [SCENE…] [-- AUGSPLAT-RUN-ARGS…]
#
# SCENE: generated dtu_scan24 bonsai fern horns (the default: all five). --fragment NAME adds
# pipelines/fragments/NAME.ron to every scene's pipeline; --improved is our three presets,
# `--fragment improved_baseline --fragment improved_dual --fragment improved_staged` (only
# what they change reruns).
# Arguments after `--` go to `augsplat run` (e.g. `--set baseline.densify.reset=Never`).
#
# The whole study takes hours on a 2-core machine (docs/results.md gives the times); each
# scene's fields, renders and ensemble are shared by its three seeds and by every preset, and
# everything is cached, so a rerun or a second preset pays only for what changed. Needs
# ../shared/data beside the repository and a release build (cargo build --release).
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/paper[+NAME…]/<scene>/ (the
# evaluations, via --out), <scene>.summary.json (each node's compute seconds) and <scene>.log;
# the Markdown tables on stdout (docs/scripts/paper_table.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
fragments=()
scenes=()
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --improved) fragments+=(improved_baseline improved_dual improved_staged); shift ;;
    --fragment)
      [ $# -ge 2 ] && [ -f "$root/pipelines/fragments/$2.ron" ] \
        || { echo "--fragment needs a name from pipelines/fragments/" >&2; exit 2; }
      fragments+=("$2"); shift 2 ;;
    --) shift; extra=("$@"); break ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) scenes+=("$1"); shift ;;
  esac
done
[ ${#scenes[@]} -gt 0 ] || scenes=(generated dtu_scan24 bonsai fern horns)
preset=paper
for f in ${fragments[@]+"${fragments[@]}"}; do preset+="+$f"; done
out="$root/docs/scripts/out/$preset"
mkdir -p "$out"
targets=(--target eval_baseline --target eval_staged --target eval_dual --target eval_ensemble)
for s in "${scenes[@]}"; do
  [ -f "$root/pipelines/paper_$s.ron" ] || { echo "no pipelines/paper_$s.ron" >&2; exit 2; }
  p="$root/pipelines/paper_$s.ron"
  if [ ${#fragments[@]} -gt 0 ]; then
    list="\"$p\""
    for f in "${fragments[@]}"; do list+=", \"$root/pipelines/fragments/$f.ron\""; done
    p="$out/paper_$s.ron"
    printf '(extends: [%s])\n' "$list" >"$p"
  fi
  echo "== $s ($preset) $(date -u +%FT%TZ)" >&2
  rm -rf "${out:?}/$s"
  "$bin" run "$p" -q --log "${targets[@]}" ${extra[@]+"${extra[@]}"} --out "$out/$s" \
    --summary-json "$out/$s.summary.json" >"$out/$s.log" 2>&1 \
    || { echo "run of $s failed: see $out/$s.log" >&2; exit 1; }
done
python3 "$root/docs/scripts/paper_table.py" "$out" "${scenes[@]}"
