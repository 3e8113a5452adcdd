#!/usr/bin/env python3
"""Writes tests/pinned/gsplat_parity.json from a parity recording (see record.sh):

    pin.py OUT DEST SET...

OUT holds `ref_<seed>.json` (gsplat_reference.py's outputs, any number of seeds) and
`ours.json` (the split's output manifests and augsplat's curves on the same case, one per
optimiser seed, starting at seed 0); SET... are the `--set`s that define the case, stored for
the test to reuse; PIN_NOTE, when set, is stored as `reference_inputs_note` (how and where
the reference's seeds were recorded). The test reruns augsplat's first TEST_SEEDS seeds (a
few seconds each; one run of this case moves by about 0.5 dB (sd) with its seed, so fewer
seeds would make its threshold a coin toss); the mean over all of augsplat's recorded seeds
is stored beside them."""
import glob
import json
import os
import re
import statistics
import sys

TEST_SEEDS = 10

out, dest, sets = sys.argv[1], sys.argv[2], sys.argv[3:]
ref_files = sorted(glob.glob(f"{out}/ref_*.json"),
                   key=lambda p: int(re.search(r"ref_(\d+)\.json$", p).group(1)))
refs = [json.load(open(p)) for p in ref_files]
ours = json.load(open(f"{out}/ours.json"))
steps = [p["step"] for p in refs[0]["curve"]]
our_seeds = ours.get("seeds", list(range(len(ours["ours"]))))
if our_seeds[:TEST_SEEDS] != list(range(TEST_SEEDS)):
    sys.exit(f"augsplat's seeds must start 0 .. {TEST_SEEDS - 1} (the test reruns those): "
             f"{our_seeds}")


def rows_of(curves):
    """Per step: mean, sd and per-seed PSNR and the mean Gaussian count over `curves`, each a
    {step: (psnr, gaussians)} of one seed."""
    rows = []
    for step in steps:
        v = [c[step][0] for c in curves]
        g = [c[step][1] for c in curves]
        rows.append({"step": step, "psnr_mean": statistics.mean(v),
                     "psnr_sd": statistics.stdev(v), "psnr_seeds": v,
                     "gaussians_mean": statistics.mean(g)})
    return rows


ref_curves = [{p["step"]: (p["psnr"], p["gaussians"]) for p in r["curve"]} for r in refs]
our_curves = [{p["step"]: (p["psnr"], p["primitives"]) for p in c["points"]}
              for c in ours["ours"]]
reference = rows_of(ref_curves)
ours_rows = rows_of(our_curves[:TEST_SEEDS])
ours_all = rows_of(our_curves)
doc = {
    "_about": "Held-out PSNR of an independent gsplat-1.5.3 trainer "
              f"(docs/scripts/parity/gsplat_reference.py, seeds {[r['seed'] for r in refs]}) "
              "on the parity case; regenerate with docs/scripts/parity/record.sh. "
              "tests/gsplat_parity.rs runs augsplat's baseline on the same case with optimiser "
              "seeds 0-9 and checks that its mean final held-out PSNR does not fall more than "
              "`below_db` under the reference's mean nor rise more than `above_db` over it. "
              "`augsplat_all_seeds` is augsplat over every recorded seed, the figure the docs "
              "compare with the reference.",
    "pipeline": "pipelines/demo.ron",
    "sets": sets,
    "split_outputs": ours["split"],
    "below_db": 0.6,
    "above_db": 1.0,
    "reference": reference,
    "reference_seeds": [r["seed"] for r in refs],
    "reference_seconds": [r["seconds"] for r in refs],
    "augsplat_seeds": our_seeds[:TEST_SEEDS],
    "augsplat_when_recorded": ours_rows,
    "augsplat_all_seeds": {"seeds": our_seeds, "rows": ours_all},
}
if os.environ.get("PIN_NOTE"):
    doc["reference_inputs_note"] = os.environ["PIN_NOTE"]
with open(dest, "w") as f:
    json.dump(doc, f, indent=1)
    f.write("\n")
print(f"wrote {dest}")
for r, o, a in zip(reference, ours_rows, ours_all):
    print(f"step {r['step']:5}: reference {r['psnr_mean']:.3f} ± {r['psnr_sd']:.3f} dB "
          f"({r['gaussians_mean']:.0f} Gaussians, {len(refs)} seeds), augsplat "
          f"{o['psnr_mean']:.3f} ± {o['psnr_sd']:.3f} dB ({o['gaussians_mean']:.0f}, "
          f"{TEST_SEEDS} seeds), {a['psnr_mean']:.3f} ± {a['psnr_sd']:.3f} dB "
          f"({a['gaussians_mean']:.0f}, {len(ours['ours'])} seeds)")
