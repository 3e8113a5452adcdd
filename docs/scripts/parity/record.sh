#!/usr/bin/env bash
# Records the independent gsplat-1.5.3 reference (gsplat_reference.py) on the parity case and
# writes tests/pinned/gsplat_parity.json, which tests/gsplat_parity.rs compares augsplat's
# baseline against. Run from the repository root:
#
#   PYTHON=/path/to/python-with-torch docs/scripts/parity/record.sh
#
# PYTHON needs torch (CPU is enough), numpy and Pillow. The reference takes 30-60 min per
# seed on one core (REF_SEEDS, default 0-4, two at a time: about 2 hours on 2 cores);
# augsplat a few seconds per seed (OUR_SEEDS, default 0-19, starting at 0: the test reruns
# the first ten). The case — the generated scene at 96×72, 26 / 4 views, its 2,990 SfM
# points, 1,000 steps, the densification schedule scaled as augsplat scales it — is defined
# once, by SETS below, which go into the JSON for the test to reuse.
set -euo pipefail
PYTHON=${PYTHON:-python3}
root=$(pwd)
out=${OUT:-$root/docs/scripts/out/parity}
mkdir -p "$out"
SETS=(
  scene.width=96 scene.height=72 params.gs_steps=1000 params.eval_every=100
  params.max_gaussians=0 params.lpips=None
  baseline.real_loss.kind=L1 baseline.densify.reset=Never baseline.max_alpha=0.999
)
# augsplat's scaled schedule for 1,000 of 30,000 reference steps (DensifyArgs::scaled):
# start 500·¼, stop 15000/30, every min(100, (stop − start)/4), reset every 3000·¼.
SCHEDULE=(--start 125 --stop 500 --every 93 --reset-every 750)

cargo build --release -q --bin augsplat
bin=$root/target/release/augsplat
set_args=()
for s in "${SETS[@]}"; do set_args+=(--set "$s"); done
rm -rf "$out/cache"
REF_SEEDS=${REF_SEEDS:-0 1 2 3 4}
OUR_SEEDS=${OUR_SEEDS:-$(seq 0 19)}
for seed in $OUR_SEEDS; do
  "$bin" run pipelines/demo.ron --cache "$out/cache" --target eval_baseline -q \
    --summary-json "$out/summary_$seed.json" "${set_args[@]}" --set "baseline.seed=$seed"
done

# The split's outputs (the reference's inputs) and augsplat's own curves.
"$PYTHON" - "$out" $OUR_SEEDS <<'EOF'
import json, sys
out, seeds = sys.argv[1], [int(s) for s in sys.argv[2:]]
curves = []
for seed in seeds:
    nodes = {n["name"]: n for n in json.load(open(f"{out}/summary_{seed}.json"))["nodes"]}
    def outputs(name):
        k = nodes[name]["key"]
        return json.load(open(f"{out}/cache/actions/{k[:2]}/{k}.json"))["outputs"]
    split = outputs("split")
    curves.append(json.load(open(f"{out}/cache/outputs/{outputs('baseline')['model']}/curve.json")))
open(f"{out}/dirs", "w").write(
    f"{out}/cache/outputs/{split['train']}\n{out}/cache/outputs/{split['test']}\n")
json.dump({"split": split, "seeds": seeds, "ours": curves}, open(f"{out}/ours.json", "w"))
EOF
mapfile -t dirs < "$out/dirs"

rm -f "$out"/ref_*.json
running=0
for s in $REF_SEEDS; do
  "$PYTHON" docs/scripts/parity/gsplat_reference.py "${dirs[0]}" "${dirs[1]}" --steps 1000 \
    --seed "$s" --threads 1 "${SCHEDULE[@]}" --out "$out/ref_$s.json" > "$out/ref_$s.log" 2>&1 &
  running=$((running + 1))
  if [ "$running" = 2 ]; then wait; running=0; fi
done
wait

"$PYTHON" docs/scripts/parity/pin.py "$out" "$root/tests/pinned/gsplat_parity.json" "${SETS[@]}"
