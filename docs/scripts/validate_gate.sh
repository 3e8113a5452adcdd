#!/usr/bin/env bash
# Validates the scene gate (pipelines/fragments/gate.ron) on the generated scene and the real captures:
# for each scene, runs the gated pipeline with the gate forced open, so the same run holds the
# gate's evidence (what it would decide) AND the methods' held-out results (whether the
# method actually helped), then prints one table row per scene.
#
#   bash docs/scripts/validate_gate.sh [SCENE…]      (default: demo fern horns dtu_scan24 bonsai)
#
# Real scenes run at the reduced sizes of the README's bonsai run (fields 400 steps, Gaussians
# 1,500 steps, at most 60k). Needs ../shared/data beside the repository and a release build.
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/<scene>.summary.json and a
# Markdown table on stdout.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
out="$root/docs/scripts/out"
mkdir -p "$out"
export AUGSPLAT_LPIPS_WEIGHTS="$root/../shared/data/lpips"
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(demo fern horns dtu_scan24 bonsai)
reduced=(--set field.steps=400 --set params.gs_steps=1500 --set params.max_gaussians=60000)
for s in "${scenes[@]}"; do
  p="$out/${s}_gated.ron"
  printf '(extends: ["%s/pipelines/%s.ron", "%s/pipelines/fragments/gate.ron"])\n' "$root" "$s" "$root" >"$p"
  sets=(--set 'gate.force=Some(true)')
  [ "$s" = demo ] || sets+=("${reduced[@]}")
  echo "== $s" >&2
  "$bin" run "$p" -q "${sets[@]}" --summary-json "$out/$s.summary.json" >"$out/$s.log" 2>&1 \
    || { echo "run of $s failed: see $out/$s.log" >&2; exit 1; }
done
python3 "$root/docs/scripts/gate_table.py" "$out" "${scenes[@]}"
