#!/usr/bin/env bash
# The validation study: every scene through the paper's protocol with our improved presets,
# optimiser seeds 0-4, each method without and with DropGaussian, and the scene gate beside it
# (forced open, so every method runs and the gate's choice is recorded, never used to skip),
# then the tables with seed-paired statistics (docs/scripts/study_table.py).
#
#   bash docs/scripts/validation_study.sh [--validation] [SCENE…] [-- AUGSPLAT-RUN-ARGS…]
#
# SCENE: generated dtu_scan24 bonsai fern horns (the default: all five development scenes).
# --validation adds maryrose, the validation capture, which is run once with the configuration
# frozen before (the presets, the gate and this script at the commit the run names): the
# script refuses it when pipelines/ or this script differ from the last commit, and writes the
# commit beside its results (maryrose.commit).
#
# Each scene's pipeline: pipelines/paper_<scene>.ron, fragments/gate.ron,
# fragments/improved_{baseline,staged,dual}.ron and fragments/dropgaussian_seeds.ron (whose
# first five points are fragments/five_seeds.ron's, with the same keys); where the scene
# triangulates its points (fragments/triangulated.ron), the gate's rehearsals start from them
# too. Everything is cached: a rerun or an interrupted study resumes where it stopped. On a
# 2-core machine the
# study takes a day or more; run it niced in the background.
# Binary: $AUGSPLAT_BIN or target/release/augsplat (a copy keeps a long study off later builds).
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/validation/<scene>/ (the
# evaluations and the gate's evidence, via --out), <scene>.summary.json and <scene>.log; the
# tables on stdout.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="${AUGSPLAT_BIN:-$root/target/release/augsplat}"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
# The gate's rehearsals read the installed LPIPS weights.
export AUGSPLAT_LPIPS_WEIGHTS="${AUGSPLAT_LPIPS_WEIGHTS:-$root/../shared/data/lpips}"
scenes=()
extra=()
validation=false
while [ $# -gt 0 ]; do
  case "$1" in
    --validation) validation=true; shift ;;
    --) shift; extra=("$@"); break ;;
    -*) echo "unknown option $1" >&2; exit 2 ;;
    *) scenes+=("$1"); shift ;;
  esac
done
[ ${#scenes[@]} -gt 0 ] || scenes=(generated dtu_scan24 bonsai fern horns)
if $validation; then
  if ! git diff --quiet HEAD -- pipelines docs/scripts/validation_study.sh; then
    echo "maryrose runs only with the committed configuration: commit or revert pipelines/ first" >&2
    exit 1
  fi
  scenes+=(maryrose)
fi
out="$root/docs/scripts/out/validation"
mkdir -p "$out"
targets=(--target eval_baseline --target eval_staged --target eval_dual --target eval_ensemble
  --target gate)
for s in "${scenes[@]}"; do
  [ -f "$root/pipelines/paper_$s.ron" ] || { echo "no pipelines/paper_$s.ron" >&2; exit 2; }
  p="$out/paper_$s.ron"
  list="\"$root/pipelines/paper_$s.ron\", \"$root/pipelines/fragments/gate.ron\""
  for f in improved_baseline improved_staged improved_dual dropgaussian_seeds; do
    list+=", \"$root/pipelines/fragments/$f.ron\""
  done
  nodes=""
  if grep -q 'fragments/triangulated.ron' "$root/pipelines/paper_$s.ron"; then
    nodes=', nodes: { "gate_split": (inputs: { "scene": "points.scene" }) }'
  fi
  printf '(extends: [%s]%s)\n' "$list" "$nodes" >"$p"
  echo "== $s $(date -u +%FT%TZ)" >&2
  [ "$s" != maryrose ] || git rev-parse HEAD >"$out/maryrose.commit"
  rm -rf "${out:?}/$s"
  "$bin" run "$p" -q --log --set 'gate.force=Some(true)' "${targets[@]}" \
    ${extra[@]+"${extra[@]}"} --out "$out/$s" --summary-json "$out/$s.summary.json" \
    >"$out/$s.log" 2>&1 || { echo "run of $s failed: see $out/$s.log" >&2; exit 1; }
done
python3 "$root/docs/scripts/study_table.py" "$out" "${scenes[@]}"
