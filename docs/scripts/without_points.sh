#!/usr/bin/env bash
# Reruns docs/results.md's *Without SfM points*: the 3DGS baseline started from random
# points between the scene's bounds against the same baseline started from the radiance-field
# prior's depth (pipelines/fragments/depth_init.ron: field[0]'s renders at the training
# views), on fern (LLFF: no SfM points, bounds from poses_bounds.npy) and on dtu_scan24 with
# its SfM points removed (bounds from where the cameras' optical axes converge), at the
# README's reduced sizes. Prints a Markdown table.
#
#   bash docs/scripts/without_points.sh
#
# Needs ../shared/data beside the repository and a release build (cargo build --release).
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/without_points/ (the points-free
# copy of dtu_scan24's COLMAP model, the pipelines, each run's evaluation and summary).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
out="$root/docs/scripts/out/without_points"
mkdir -p "$out"

source "$root/docs/scripts/dtu_without_points.sh"
nop="$out/dtu_scan24_nopoints"
dtu_without_points "$root/../shared/data/dtu_scan24" "$nop"

sizes=(--set field.steps=400 --set params.gs_steps=1500 --set params.max_gaussians=60000)
for scene in fern dtu_scan24; do
  for start in random depth; do
    nodes=""
    [ "$scene" = dtu_scan24 ] && nodes+="\"scene\": (inputs: { \"source\": Path(\"$nop\") }), "
    [ "$start" = depth ] && nodes+="\"baseline\": (inputs: { \"init_depth\": \"render_train.renders\" }), "
    p="$out/${scene}_$start.ron"
    printf '(extends: ["%s/pipelines/%s.ron", "%s/pipelines/fragments/depth_init.ron"], nodes: { %s})\n' \
      "$root" "$scene" "$root" "$nodes" >"$p"
    echo "== $scene, $start start $(date -u +%FT%TZ)" >&2
    rm -rf "${out:?}/${scene}_$start"
    "$bin" run "$p" -q --log "${sizes[@]}" --target eval_baseline \
      --out "$out/${scene}_$start" --summary-json "$out/${scene}_$start.summary.json" \
      >"$out/${scene}_$start.log" 2>&1 \
      || { echo "run of ${scene}_$start failed: see $out/${scene}_$start.log" >&2; exit 1; }
  done
done

python3 - "$out" <<'EOF'
import json, re, sys
from pathlib import Path

out = Path(sys.argv[1])
print("| scene | start | held-out PSNR / SSIM / LPIPS / avg. error | Gaussians |")
print("|---|---|---|---:|")
for scene in ["fern", "dtu_scan24"]:
    for start in ["random", "depth"]:
        run = out / f"{scene}_{start}"
        m = json.loads((run / "eval_baseline" / "eval" / "metrics.json").read_text())["mean"]
        header = (run / "eval_baseline" / "eval" / "model.ply").read_bytes()[:512]
        count = int(re.search(rb"element vertex (\d+)", header).group(1))
        label = "the prior's depth (field[0])" if start == "depth" else "random between the bounds"
        print(f"| {scene} | {label} | {m['psnr']:.2f} / {m['ssim']:.3f} / {m['lpips']:.3f} / "
              f"{m['avg_error']:.4f} | {count:,} |")
EOF
