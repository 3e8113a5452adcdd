#!/usr/bin/env bash
# Measures the demo end to end on a fresh store and writes its figure as a benchmark record
# (the JSON that docs/scripts/current_table.py renders into docs/current.md):
#
#   bash docs/scripts/demo_record.sh [RECORD.json]     # default: docs/figures/01_demo.json
#
# The run: `augsplat run pipelines/demo.ron` on an empty temporary store (its wall time and
# node count); then the same pipeline again, all cached, copying the three evaluations out
# (held-out PSNR, LPIPS and average error of 3DGS, Staged and Dual at their best step).
# Needs a release build (cargo build --release).
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
python3 - "$work" "$start" "$end" "$record" <<'EOF'
import json, os, platform, subprocess, sys
work, start, end, record = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
nodes = json.load(open(f"{work}/summary.json"))["nodes"]
ran = sum(1 for n in nodes if n["status"] == "ran")
best = {}
for node, label in [("eval_baseline", "3DGS"), ("eval_staged", "Staged"), ("eval_dual", "Dual")]:
    best[label] = json.load(open(f"{work}/out/{node}/eval/metrics.json"))["best"]["point"]
def row(metric, digits):
    return " / ".join(f"{best[m][metric]:.{digits}f}" for m in best)
wall = end - start
figure = (f"{ran} nodes in {wall:.1f} s; held-out PSNR 3DGS / Staged / Dual {row('psnr', 2)} dB; "
          f"LPIPS {row('lpips', 3)}; average error {row('avg_error', 3)}")
commit = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], capture_output=True,
                        text=True).stdout.strip() or "unknown"
# The machine in the words of augsplat_core::bench_record::machine.
info = open("/proc/cpuinfo").read() if os.path.exists("/proc/cpuinfo") else ""
def field(key):
    for line in info.splitlines():
        k, _, v = line.partition(":")
        if k.strip() == key:
            return v.strip()
    return None
model = field("model name") or platform.machine()
gen = None
if field("vendor_id") == "AuthenticAMD":
    fam = field("cpu family")
    avx512 = "avx512f" in (field("flags") or "").split()
    gen = {"23": "Zen 2 or older", "25": "Zen 4" if avx512 else "Zen 3", "26": "Zen 5"}.get(fam)
if gen and "Zen" not in model:
    model = f"{model} ({gen})"
out = {
    "what": "the demo, end to end, fresh store",
    "command": "cargo run --release -- run pipelines/demo.ron",
    "figure": figure,
    "value": round(wall, 2),
    "unit": "s",
    "commit": commit,
    "date": subprocess.run(["date", "-u", "+%F"], capture_output=True, text=True).stdout.strip(),
    "machine": f"{model}, {len(os.sched_getaffinity(0))} cores",
}
with open(record, "w") as f:
    json.dump(out, f, indent=2, ensure_ascii=False)
    f.write("\n")
print(f"record written: {record}\n{figure}")
EOF
