#!/usr/bin/env python3
"""How the radiance-field prior's held-out errors sit against a 3DGS baseline's, per pixel.

    python3 docs/scripts/prior_complementarity.py SCENE ENSEMBLE_EVAL BASELINE_EVAL...

ENSEMBLE_EVAL is the `eval` folder of an `eval_ensemble` output (`augsplat run … --target
eval_ensemble --out DIR` writes DIR/eval_ensemble/eval); each BASELINE_EVAL the `eval` folder
of one seed's `eval_baseline@…` output. Both hold `gt/` and `renders/` (8-bit PNGs of the
held-out views). Prints one Markdown row: the prior's squared error against the baseline's,
the share of pixels where the prior is closer to the ground truth, and the "oracle" — the
error left if each pixel (or each 16 × 16 patch) took whichever of the two is closer, as a
fraction of the baseline's — each the mean over the baseline seeds given (min–max beside).

This reads held-out views: it is an analysis of finished runs (docs/notes/results.md, *What does
not explain which scenes gain*), never an input to a run or to the scene gate. Needs numpy
and Pillow.
"""
import glob
import os
import sys

import numpy as np
from PIL import Image

PATCH = 16


def load(folder):
    files = sorted(glob.glob(os.path.join(folder, "*.png")))
    if not files:
        sys.exit(f"no PNG in {folder}")
    return {
        os.path.basename(f): np.asarray(Image.open(f).convert("RGB"), dtype=np.float64) / 255
        for f in files
    }


def patch_means(se):
    h, w = (se.shape[0] // PATCH) * PATCH, (se.shape[1] // PATCH) * PATCH
    return se[:h, :w].reshape(h // PATCH, PATCH, w // PATCH, PATCH).mean(axis=(1, 3)).ravel()


def compare(gt, prior, base):
    if base.keys() != gt.keys():
        sys.exit("the baseline's held-out views are not the ensemble's")
    px_b, px_p, pa_b, pa_p = [], [], [], []
    for name, target in gt.items():
        eb = ((base[name] - target) ** 2).mean(axis=-1)
        ep = ((prior[name] - target) ** 2).mean(axis=-1)
        px_b.append(eb.ravel())
        px_p.append(ep.ravel())
        pa_b.append(patch_means(eb))
        pa_p.append(patch_means(ep))
    sb, sp = np.concatenate(px_b), np.concatenate(px_p)
    pb, pp = np.concatenate(pa_b), np.concatenate(pa_p)
    return {
        "ratio": sp.mean() / sb.mean(),
        "px_better": (sp < sb).mean(),
        "px_oracle": np.minimum(sb, sp).mean() / sb.mean(),
        "patch_oracle": np.minimum(pb, pp).mean() / pb.mean(),
    }


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    scene, ens = sys.argv[1], sys.argv[2]
    gt = load(os.path.join(ens, "gt"))
    prior = load(os.path.join(ens, "renders"))
    rows = [compare(gt, prior, load(os.path.join(b, "renders"))) for b in sys.argv[3:]]

    def cell(key, pct=False):
        v = np.array([r[key] for r in rows]) * (100 if pct else 1)
        fmt = "{:.1f} %" if pct else "{:.2f}"
        return f"{fmt.format(v.mean())} ({fmt.format(v.min())}–{fmt.format(v.max())})"

    print(
        f"| {scene} | {len(rows)} | {cell('ratio')} | {cell('px_better', True)} "
        f"| {cell('px_oracle')} | {cell('patch_oracle')} |"
    )


if __name__ == "__main__":
    main()
