#!/usr/bin/env bash
# Reruns docs/results.md's *Captures without SfM points*: pipelines/capture.ron on dtu_scan24
# with its SfM points, on dtu_scan24 with them removed, and on LLFF fern and horns (no points
# shipped), each without points started two ways: from points triangulated from the training
# photos (TriangulatePoints, capture.ron's default) and from random points between the bounds
# (`"points": (args: (when: Never))`, what capture.ron did before it triangulated). Prints a
# Markdown table: held-out PSNR / SSIM / LPIPS / average error of 3DGS, Staged and Dual (a
# dash where the scene gate skipped them), the start's point count and the triangulation time.
# Rows `triangulated, gate forced` run Staged and Dual whatever the gate says
# (`--set gate.force=Some(true)`), to show what the gate skipped.
#
#   bash docs/scripts/capture_points.sh
#
# Needs ../shared/data beside the repository and a release build (cargo build --release).
# Store: $AUGSPLAT_CACHE or ./cache. Output: docs/scripts/out/capture_points/.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
out="$root/docs/scripts/out/capture_points"
mkdir -p "$out"
data="$root/../shared/data"

source "$root/docs/scripts/dtu_without_points.sh"
nop="$out/dtu_scan24_nopoints"
dtu_without_points "$data/dtu_scan24" "$nop"

runs=(
  "dtu_scan24|$data/dtu_scan24|sfm"
  "dtu_scan24_nopoints|$nop|triangulated"
  "dtu_scan24_nopoints|$nop|forced"
  "dtu_scan24_nopoints|$nop|random"
  "fern|$data/fern|triangulated"
  "fern|$data/fern|forced"
  "fern|$data/fern|random"
  "horns|$data/horns|triangulated"
  "horns|$data/horns|forced"
  "horns|$data/horns|random"
)
for r in "${runs[@]}"; do
  IFS='|' read -r scene src start <<<"$r"
  extra=""
  sets=()
  [ "$start" = random ] && extra=', "points": (args: (when: Never))'
  [ "$start" = forced ] && sets=(--set 'gate.force=Some(true)')
  name="${scene}_$start"
  p="$out/$name.ron"
  printf '(extends: "%s/pipelines/capture.ron", nodes: { "scene": (inputs: { "source": Path("%s") })%s })\n' \
    "$root" "$src" "$extra" >"$p"
  echo "== $name $(date -u +%FT%TZ)" >&2
  rm -rf "${out:?}/$name"
  "$bin" run "$p" -q --log "${sets[@]}" --out "$out/$name" --summary-json "$out/$name.summary.json" \
    >"$out/$name.log" 2>&1 || { echo "run of $name failed: see $out/$name.log" >&2; exit 1; }
  # The per-method evaluations (the report is the pipeline's only leaf).
  for m in baseline staged dual; do
    "$bin" run "$p" -q "${sets[@]}" --target "eval_$m" --out "$out/$name" >/dev/null 2>&1 || true
  done
done

python3 - "$out" "${runs[@]}" <<'EOF'
import json, re, sys
from pathlib import Path

out = Path(sys.argv[1])
print("| scene | start | points | triangulation s | 3DGS | Staged | Dual |")
print("|---|---|---:|---:|---|---|---|")
for r in sys.argv[2:]:
    scene, _, start = r.split("|")
    run = out / f"{scene}_{start}"
    log = (out / f"{scene}_{start}.log").read_text()
    cells = []
    for m in ["baseline", "staged", "dual"]:
        f = run / f"eval_{m}" / "eval" / "metrics.json"
        if f.is_file():
            x = json.loads(f.read_text())["mean"]
            cells.append(f"{x['psnr']:.2f} / {x['ssim']:.3f} / {x['lpips']:.3f} / {x['avg_error']:.4f}")
        else:
            cells.append("— (gate: skip)")
    t = re.search(r"\[points [^\]]*\] (\d+) points from .* in ([0-9.]+) s", log)
    if t:
        points, secs = f"{int(t.group(1)):,}", t.group(2)
    else:
        # Reused from the store (same key as an earlier row): no log lines.
        s = re.search(r"\[baseline [^\]]*\] .*?(\d+) initial Gaussians", log)
        points, secs = (f"{int(s.group(1)):,}" if s else "(as above)"), "—"
    label = {"forced": "triangulated, gate forced", "sfm": "SfM points"}.get(start, start)
    print(f"| {scene} | {label} | {points} | {secs} | " + " | ".join(cells) + " |")
EOF
