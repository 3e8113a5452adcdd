#!/usr/bin/env python3
"""Writes tests/pinned/gsplat_parity.json from a parity recording (see record.sh):

    pin.py OUT DEST SET...

OUT holds `ref_0.json`, `ref_1.json`, `ref_2.json` (gsplat_reference.py's outputs) and
`ours.json` (the split's output manifests and augsplat's curves for optimiser seeds 0-2
on the same case); SET... are
the `--set`s that define the case, stored for the test to reuse."""
import json
import statistics
import sys

out, dest, sets = sys.argv[1], sys.argv[2], sys.argv[3:]
refs = [json.load(open(f"{out}/ref_{s}.json")) for s in range(3)]
ours = json.load(open(f"{out}/ours.json"))
steps = [p["step"] for p in refs[0]["curve"]]
rows = []
for i, step in enumerate(steps):
    v = [r["curve"][i]["psnr"] for r in refs]
    g = [r["curve"][i]["gaussians"] for r in refs]
    rows.append({"step": step, "psnr_mean": statistics.mean(v), "psnr_sd": statistics.stdev(v),
                 "psnr_seeds": v, "gaussians_mean": statistics.mean(g)})
ours_rows = []
for step in steps:
    v = [next(p["psnr"] for p in c["points"] if p["step"] == step) for c in ours["ours"]]
    g = [next(p["primitives"] for p in c["points"] if p["step"] == step) for c in ours["ours"]]
    ours_rows.append({"step": step, "psnr_mean": statistics.mean(v),
                      "psnr_sd": statistics.stdev(v), "psnr_seeds": v,
                      "gaussians_mean": statistics.mean(g)})
doc = {
    "_about": "Held-out PSNR of an independent gsplat-1.5.3 trainer "
              "(docs/scripts/parity/gsplat_reference.py, seeds 0-2) on the parity case; "
              "regenerate with docs/scripts/parity/record.sh. tests/gsplat_parity.rs runs "
              "augsplat's baseline on the same case with optimiser seeds 0-2 and checks "
              "that its mean final held-out PSNR does not fall more than `below_db` under the "
              "reference's mean nor rise more than `above_db` over it.",
    "pipeline": "pipelines/demo.ron",
    "sets": sets,
    "split_outputs": ours["split"],
    "below_db": 0.6,
    "above_db": 1.0,
    "reference": rows,
    "reference_seconds": [r["seconds"] for r in refs],
    "augsplat_seeds": [0, 1, 2],
    "augsplat_when_recorded": ours_rows,
}
with open(dest, "w") as f:
    json.dump(doc, f, indent=1)
    f.write("\n")
print(f"wrote {dest}")
for r, o in zip(rows, ours_rows):
    print(f"step {r['step']:5}: reference {r['psnr_mean']:.3f} ± {r['psnr_sd']:.3f} dB "
          f"({r['gaussians_mean']:.0f} Gaussians), augsplat {o['psnr_mean']:.3f} ± "
          f"{o['psnr_sd']:.3f} dB ({o['gaussians_mean']:.0f})")
