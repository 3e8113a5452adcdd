#!/usr/bin/env python3
"""The paper-protocol tables of docs/results.md from the evaluations `paper_study.sh` copied out.

    python3 docs/scripts/paper_table.py OUT_DIR [SCENE...]

OUT_DIR/<scene>/ holds `augsplat run … --out` folders: eval_baseline@…, eval_staged@…,
eval_dual@… (one per optimiser seed, named by the sweep point) and eval_ensemble. For each
scene: held-out PSNR / SSIM / LPIPS / average error, mean ± sd over the seeds, each method at
its best checkpoint and at the baseline's best step, the Gaussian count, each seed's average
error (best step); the change of Staged's and Dual's average error against 3DGS, seed by seed;
and, when OUT_DIR/<scene>.summary.json exists, the compute seconds of the nodes that ran. Then
one row per scene and the average over the scenes of Staged, of Dual, of the better of the two
chosen after seeing all seeds, and of the better chosen for each seed on the *other* seeds
alone (leave one seed out: a seed's result never takes part in choosing the method it is
counted for, so the choice cannot favour that seed's luck).
"""

import glob
import json
import os
import re
import statistics
import sys

METHODS = [("baseline", "3DGS"), ("staged", "Staged"), ("dual", "Dual")]


def seed_of(path):
    m = re.search(r"baseline\.seed=(\d+)", path)
    return int(m.group(1)) if m else 0


def evaluations(scene_dir, method):
    """{seed: metrics.json} of one method."""
    out = {}
    for p in glob.glob(os.path.join(scene_dir, f"eval_{method}*", "eval", "metrics.json")):
        with open(p) as f:
            out[seed_of(p)] = json.load(f)
    return out


def mean_sd(xs):
    if not xs:
        return float("nan"), float("nan")
    return statistics.mean(xs), (statistics.stdev(xs) if len(xs) > 1 else 0.0)


def at_baseline(m):
    ab = m.get("at_baseline") or {}
    point = ab.get("point")
    return point["avg_error"] if point and point.get("avg_error") is not None else None


def leave_one_seed_out(evals):
    """The change (%) against 3DGS of the method chosen, for each seed, by the lower mean average
    error of Staged and Dual over the other seeds; and the choices ("S" / "D" per seed)."""
    base, staged, dual = evals["baseline"], evals["staged"], evals["dual"]
    seeds = sorted(set(base) & set(staged) & set(dual))
    if len(seeds) < 2:
        return None, ""
    err = lambda runs, s: runs[s]["mean"]["avg_error"]
    chosen, picks = [], ""
    for s in seeds:
        others = [t for t in seeds if t != s]
        m_staged = statistics.mean(err(staged, t) for t in others)
        m_dual = statistics.mean(err(dual, t) for t in others)
        runs = dual if m_dual <= m_staged else staged
        picks += "D" if runs is dual else "S"
        chosen.append(err(runs, s))
    b = statistics.mean(err(base, s) for s in seeds)
    return 100.0 * (statistics.mean(chosen) - b) / b, picks


def scene_table(out_dir, scene):
    d = os.path.join(out_dir, scene)
    evals = {key: evaluations(d, key) for key, _ in METHODS}
    if not any(evals.values()):
        print(f"**{scene}**: no evaluations in {d}\n")
        return None
    print(f"**{scene}**\n")
    print("| | PSNR | SSIM | LPIPS | avg. error | at 3DGS's best step | Gaussians | per seed (best step) |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    ens = os.path.join(d, "eval_ensemble", "eval", "metrics.json")
    if os.path.exists(ens):
        with open(ens) as f:
            e = json.load(f)
        med = e["median"]["mean"]
        print(f"| ensemble median (M = {e.get('members', '?')}) | {med['psnr']:.2f} | "
              f"{med['ssim']:.3f} | {med['lpips']:.3f} | {med['avg_error']:.4f} | — | — | — |")
    for key, label in METHODS:
        runs = evals[key]
        if not runs:
            continue
        seeds = sorted(runs)
        col = lambda k: [runs[s]["mean"][k] for s in seeds]
        psnr, ae = mean_sd(col("psnr")), mean_sd(col("avg_error"))
        ab = [at_baseline(runs[s]) for s in seeds]
        ab = mean_sd([x for x in ab if x is not None]) if any(x is not None for x in ab) else None
        gauss = statistics.mean(runs[s].get("primitives") or 0 for s in seeds)
        per_seed = ", ".join(
            f"{runs[s]['mean']['avg_error']:.4f} ({runs[s].get('checkpoint_step')})" for s in seeds
        )
        ab_text = f"{ab[0]:.4f}" if ab else ("(its own)" if key == "baseline" else "—")
        print(f"| {label} | {psnr[0]:.2f} ± {psnr[1]:.2f} | {statistics.mean(col('ssim')):.3f} | "
              f"{statistics.mean(col('lpips')):.3f} | {ae[0]:.4f} ± {ae[1]:.4f} | {ab_text} | "
              f"{gauss:,.0f} | {per_seed} |")
    print()
    base = evals["baseline"]
    changes = {}
    for key, label in METHODS[1:]:
        runs = evals[key]
        common = sorted(set(runs) & set(base))
        if not common:
            continue
        b = statistics.mean(base[s]["mean"]["avg_error"] for s in common)
        m = statistics.mean(runs[s]["mean"]["avg_error"] for s in common)
        lower = sum(runs[s]["mean"]["avg_error"] < base[s]["mean"]["avg_error"] for s in common)
        changes[label] = 100.0 * (m - b) / b
        print(f"- {label} against 3DGS: {changes[label]:+.1f} % average error "
              f"(seeds {', '.join(map(str, common))}; lower at {lower} of {len(common)})")
    summary = os.path.join(out_dir, f"{scene}.summary.json")
    if os.path.exists(summary):
        with open(summary) as f:
            nodes = json.load(f)["nodes"]
        ran = {}
        for n in nodes:
            if n.get("status") == "ran":
                stage = re.split(r"[@\[]", n["name"])[0]
                ran[stage] = ran.get(stage, 0.0) + n.get("seconds", 0.0)
        cached = sum(n.get("status") == "cached" for n in nodes)
        if ran:
            parts = ", ".join(f"{k} {v:,.0f}" for k, v in sorted(ran.items()))
            print(f"- compute seconds of the nodes that ran: {parts}; {cached} nodes were cached")
    print()
    return evals, changes


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    out_dir = sys.argv[1]
    scenes = sys.argv[2:] or sorted(
        n for n in os.listdir(out_dir) if os.path.isdir(os.path.join(out_dir, n))
    )
    rows = []
    for s in scenes:
        r = scene_table(out_dir, s)
        if r:
            rows.append((s, r[0], r[1]))
    if not rows:
        return
    print("| scene | 3DGS avg. error | Staged | Dual | better of the two | chosen on the other seeds |")
    print("|---|---:|---:|---:|---:|---:|")
    cols = {"Staged": [], "Dual": [], "better": [], "loso": []}
    for s, evals, ch in rows:
        base = evals["baseline"]
        b = statistics.mean(v["mean"]["avg_error"] for v in base.values()) if base else float("nan")
        cells = [f"{ch[k]:+.1f} %" if k in ch else "—" for k in ("Staged", "Dual")]
        for k in ("Staged", "Dual"):
            if k in ch:
                cols[k].append(ch[k])
        better = min(ch.values()) if ch else None
        if better is not None:
            cols["better"].append(better)
        loso, picks = leave_one_seed_out(evals)
        if loso is not None:
            cols["loso"].append(loso)
        print(f"| {s} | {b:.4f} | {cells[0]} | {cells[1]} | "
              f"{f'{better:+.1f} %' if better is not None else '—'} | "
              f"{f'{loso:+.1f} % ({picks})' if loso is not None else '—'} |")
    avg = {k: (f"{statistics.mean(v):+.1f} % ({len(v)})" if v else "—") for k, v in cols.items()}
    print(f"| average (scenes) | | {avg['Staged']} | {avg['Dual']} | **{avg['better']}** | "
          f"**{avg['loso']}** |")


if __name__ == "__main__":
    main()
