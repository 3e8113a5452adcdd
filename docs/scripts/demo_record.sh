#!/usr/bin/env bash
# Measures the demo end to end on a fresh store and writes its figure as a benchmark record
# (the JSON that docs/scripts/current_table.py renders into docs/current.md):
#
#   bash docs/scripts/demo_record.sh [RECORD.json]     # default: docs/figures/01_demo.json
#
# The run: `augsplat run pipelines/demo.ron` on an empty temporary store (its wall time and
# node count); then the same pipeline again, all cached, copying the three evaluations out
# (held-out PSNR, LPIPS and average error of 3DGS, Staged and Dual at their best step).
# Needs a release build (cargo build --release); the record is written by augsplat-core's
# bench_record example.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
[ -x "$bin" ] || { echo "no release build: run cargo build --release first" >&2; exit 1; }
record="${1:-$root/docs/figures/01_demo.json}"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
start=$(date +%s.%N)
"$bin" run pipelines/demo.ron -q --cache "$work/store" --summary-json "$work/summary.json"
end=$(date +%s.%N)
"$bin" run pipelines/demo.ron -q --cache "$work/store" --out "$work/out" \
  --target eval_baseline --target eval_staged --target eval_dual
figure=$(python3 - "$work" "$start" "$end" <<'EOF'
import json, sys
work, start, end = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
nodes = json.load(open(f"{work}/summary.json"))["nodes"]
ran = sum(1 for n in nodes if n["status"] == "ran")
best = {}
for node, label in [("eval_baseline", "3DGS"), ("eval_staged", "Staged"), ("eval_dual", "Dual")]:
    best[label] = json.load(open(f"{work}/out/{node}/eval/metrics.json"))["best"]["point"]
def row(metric, digits):
    return " / ".join(f"{best[m][metric]:.{digits}f}" for m in best)
print(f"{ran} nodes in {end - start:.1f} s; held-out PSNR 3DGS / Staged / Dual {row('psnr', 2)} dB; "
      f"LPIPS {row('lpips', 3)}; average error {row('avg_error', 3)}")
EOF
)
wall=$(python3 -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 2))" "$start" "$end")
# The record names this commit, today and this machine as every benchmark record does.
cargo run -q --release -p augsplat-core --example bench_record -- \
  "the demo, end to end, fresh store" "cargo run --release -- run pipelines/demo.ron" \
  "$figure" "$wall" s --json "$record"
echo "$figure"
