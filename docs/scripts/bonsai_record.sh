#!/usr/bin/env bash
# Measures the reduced bonsai run on a fresh store and writes three benchmark records (the JSON
# that docs/scripts/current_table.py renders into docs/current.md):
#
#   bash docs/scripts/bonsai_record.sh [FIGURES_DIR]     # default: docs/figures
#
# 02_bonsai_reduced_run.json  the run's wall time, end to end (`augsplat run pipelines/bonsai.ron`
#                             with the reduced sizes of docs/results.md, *bonsai, reduced run*)
# 11_input_hashing.json       the seconds the engine spent hashing what each node reads before it
#                             ran (`check_seconds` of the run's action entries) against the compute
# 05_field_render.json        one trained member (field[0]) rendering its 200 synthetic views
#                             (the `bench_render` example on the run's own outputs)
#
# Takes about ten minutes on a 2-core machine; run it with nothing else running. Needs
# ../shared/data beside the repository and a release build of the CLI and the examples
# (cargo build --release --workspace --examples).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
bin="$root/target/release/augsplat"
render="$root/target/release/examples/bench_render"
for b in "$bin" "$render"; do
  [ -x "$b" ] || { echo "no release build of $b: cargo build --release --workspace --examples" >&2; exit 1; }
done
figures="${1:-$root/docs/figures}"
sets=(--set field.steps=400 --set params.gs_steps=1500 --set params.max_gaussians=60000)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
start=$(date +%s.%N)
"$bin" run pipelines/bonsai.ron -q "${sets[@]}" --cache "$work/store" --summary-json "$work/summary.json"
end=$(date +%s.%N)
"$bin" run pipelines/bonsai.ron -q "${sets[@]}" --cache "$work/store" --out "$work/out" \
  --target 'field[0]' --target poses
weights=$(dirname "$(find "$work/out/field[0]" -name config.json | head -1)")
poses=$(find "$work/out/poses" -name poses.json | head -1)
"$render" "$weights" "$poses" --json "$figures/05_field_render.json"
python3 - "$work" "$start" "$end" "$figures" "${sets[*]}" <<'EOF'
import glob, json, subprocess, sys
work, start, end, figures, sets = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4], sys.argv[5]
# Commit, date and machine as the examples' records name them (written just before).
base = json.load(open(f"{figures}/05_field_render.json"))
nodes = json.load(open(f"{work}/summary.json"))["nodes"]
ran = sum(1 for n in nodes if n["status"] == "ran")
entries = [json.load(open(f)) for f in glob.glob(f"{work}/store/actions/*/*.json")]
check = sum(e.get("check_seconds", 0.0) for e in entries)
compute = sum(e["seconds"] for e in entries)
wall = end - start
command = f"augsplat run pipelines/bonsai.ron {sets}"
def write(name, what, cmd, figure, value, unit):
    out = {"what": what, "command": cmd, "figure": figure, "value": value, "unit": unit,
           "commit": base["commit"], "date": base["date"], "machine": base["machine"]}
    with open(f"{figures}/{name}", "w") as f:
        json.dump(out, f, indent=2, ensure_ascii=False)
        f.write("\n")
    print(f"record written: {figures}/{name}: {figure}")
# The example names the run's temporary folders in its command: name the script instead.
base["command"] = "bash docs/scripts/bonsai_record.sh (bench_render on the run's field[0] and poses)"
with open(f"{figures}/05_field_render.json", "w") as f:
    json.dump(base, f, indent=2, ensure_ascii=False)
    f.write("\n")
write("02_bonsai_reduced_run.json", "bonsai reduced run, end to end, fresh store", command,
      f"{ran} nodes in {wall:.1f} s wall, {compute:.1f} s of node compute", round(wall, 1), "s")
write("11_input_hashing.json", "hashing everything each node reads, bonsai reduced run",
      "bash docs/scripts/bonsai_record.sh (`check_seconds` of the run's action entries)",
      f"{check:.2f} s of {compute:.1f} s of compute ({100 * check / compute:.2f} %)",
      round(check, 2), "s")
EOF
