#!/usr/bin/env python3
"""The validation study's tables from the folders `validation_study.sh` copied out.

    python3 docs/scripts/study_table.py OUT_DIR SCENE...

OUT_DIR/<scene>/ holds `augsplat run … --out` folders: eval_<method>@<sweep point>/eval/ (one
per optimiser seed), eval_ensemble/eval/ and gate/evidence/gate_evidence.json. Methods are
those present among: 3DGS (`baseline`), DropGaussian (`drop`), Staged, Dual, Staged +
DropGaussian (`staged_drop`), Dual + DropGaussian (`dual_drop`); and "gate's choice": for each
scene the method the gate picked from the training views alone (Staged, Dual, or 3DGS when it
picked neither), never the held-out result.

Per scene: PSNR / SSIM / LPIPS / average error, mean ± sd over the seeds (each method at its
best checkpoint); for each method its seed-paired change of average error against 3DGS
(per seed, method / 3DGS − 1), mean with a 95 % t interval over the seeds, beside the
unpaired change of the means. Overall: the mean over scenes of each scene's mean paired
change, with a 95 % t interval over the scenes (the scene is the unit), and over all
(scene, seed) pairs; then the gate's choice (with and without DropGaussian) against the
better of 3DGS and DropGaussian on each scene; last, the gate's choice against the method the
held-out views favour, with the compute its choice spares (from the store's entries:
$AUGSPLAT_CACHE or ./cache). An interval that contains zero is "no measurable gain".

`--check FILE` compares the per-scene, per-method mean metrics with FILE (JSON written by
`--json FILE`) exactly: the pinned small protocol of tests/study_pinned.rs.
"""
import glob
import json
import math
import os
import re
import statistics
import sys

METHODS = [
    ("baseline", "3DGS"),
    ("drop", "DropGaussian"),
    ("staged", "Staged"),
    ("dual", "Dual"),
    ("staged_drop", "Staged + DropGaussian"),
    ("dual_drop", "Dual + DropGaussian"),
]
METRICS = ("psnr", "ssim", "lpips", "avg_error")
# Two-sided 95 % quantiles of Student's t for 1..30 degrees of freedom.
T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
       2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
       2.060, 2.056, 2.052, 2.048, 2.045, 2.042]


def t95(df):
    return T95[df - 1] if df <= len(T95) else 1.96


def seed_of(path, method):
    m = re.search(rf"{method}\.seed=(\d+)", path)
    return int(m.group(1)) if m else 0


def evaluations(scene_dir, method):
    """{seed: mean metrics} of one method key (`baseline`, `staged_drop`, …): the folders of
    its node, with DropGaussian on (`<node>.drop_gaussians=Some…` in the sweep point) or off."""
    if method == "drop":
        node, drop = "baseline", True
    elif method.endswith("_drop"):
        node, drop = method[: -len("_drop")], True
    else:
        node, drop = method, False
    out = {}
    for p in glob.glob(os.path.join(scene_dir, f"eval_{node}@*", "eval", "metrics.json")):
        if (f"{node}.drop_gaussians=Some" in p) != drop:
            continue
        with open(p) as f:
            out[seed_of(p, node)] = json.load(f)["mean"]
    single = os.path.join(scene_dir, f"eval_{node}", "eval", "metrics.json")
    if not out and not drop and os.path.exists(single):
        with open(single) as f:
            out[0] = json.load(f)["mean"]
    return out


def gate_choice(scene_dir):
    """(method key the gate picked, or "baseline"; its evidence) or (None, None) without a gate."""
    p = os.path.join(scene_dir, "gate", "evidence", "gate_evidence.json")
    if not os.path.exists(p):
        return None, None
    with open(p) as f:
        g = json.load(f)
    if not g.get("evidence_run"):
        return "baseline", g
    return (g.get("chosen") or "Dual").lower(), g


def interval(xs):
    """(mean, half-width of the 95 % t interval) of xs; half-width nan for one value."""
    m = statistics.mean(xs)
    if len(xs) < 2:
        return m, float("nan")
    return m, t95(len(xs) - 1) * statistics.stdev(xs) / math.sqrt(len(xs))


def verdict(m, h):
    if math.isnan(h):
        return "one value"
    if m - h > 0:
        return "worse"
    if m + h < 0:
        return "gain"
    return "no measurable gain"


def pct(m, h):
    return f"{100 * m:+.1f} % ± {100 * h:.1f}" if not math.isnan(h) else f"{100 * m:+.1f} %"


def load(out_dir, scenes):
    data = {}
    for s in scenes:
        d = os.path.join(out_dir, s)
        runs = {k: evaluations(d, k) for k, _ in METHODS}
        choice, evidence = gate_choice(d)
        if choice is not None and runs.get(choice):
            runs["gate"] = runs[choice]
        with_drop = {"baseline": "drop", "staged": "staged_drop", "dual": "dual_drop"}
        if choice is not None and runs.get(with_drop[choice]):
            runs["gate_drop"] = runs[with_drop[choice]]
        data[s] = {"runs": {k: v for k, v in runs.items() if v}, "choice": choice,
                   "evidence": evidence}
        ens = os.path.join(d, "eval_ensemble", "eval", "metrics.json")
        if os.path.exists(ens):
            with open(ens) as f:
                data[s]["ensemble"] = json.load(f)["median"]["mean"]
    return data


def labels():
    return dict(METHODS + [("gate", "gate's choice"), ("gate_drop", "gate's choice + DropGaussian")])


def scene_table(scene, d):
    names = labels()
    runs = d["runs"]
    if "baseline" not in runs:
        print(f"**{scene}**: no 3DGS evaluations\n")
        return {}
    print(f"**{scene}**" + (f" (gate's choice: {names[d['choice']]})" if d["choice"] else ""))
    print()
    print("| | PSNR | SSIM | LPIPS | avg. error | seeds | paired change vs 3DGS (95 %) | unpaired |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    if "ensemble" in d:
        e = d["ensemble"]
        print(f"| ensemble median | {e['psnr']:.2f} | {e['ssim']:.3f} | {e['lpips']:.3f} | "
              f"{e['avg_error']:.4f} | — | — | — |")
    base = runs["baseline"]
    paired = {}
    for key, r in runs.items():
        seeds = sorted(r)
        cells = []
        for k in METRICS:
            vals = [r[s][k] for s in seeds]
            sd = statistics.stdev(vals) if len(vals) > 1 else 0.0
            digits = 2 if k == "psnr" else (4 if k == "avg_error" else 3)
            cells.append(f"{statistics.mean(vals):.{digits}f} ± {sd:.{digits}f}")
        common = sorted(set(seeds) & set(base))
        if key == "baseline" or not common:
            change, unpaired = "—", "—"
        else:
            diffs = [r[s]["avg_error"] / base[s]["avg_error"] - 1.0 for s in common]
            paired[key] = diffs
            m, h = interval(diffs)
            change = f"{pct(m, h)} ({verdict(m, h)})"
            mb = statistics.mean(base[s]["avg_error"] for s in common)
            unpaired = f"{100 * (statistics.mean(r[s]['avg_error'] for s in common) / mb - 1):+.1f} %"
        print(f"| {names[key]} | {' | '.join(cells)} | {len(seeds)} | {change} | {unpaired} |")
    print()
    return paired


def overall(per_scene):
    names = labels()
    keys = [k for k in list(dict(METHODS)) + ["gate", "gate_drop"]
            if any(k in p for p in per_scene.values())]
    if not keys:
        return
    print("| method | scenes | mean paired change vs 3DGS, over scenes (95 %) | "
          "over (scene, seed) pairs (95 %) |")
    print("|---|---:|---:|---:|")
    for k in keys:
        scene_means = [statistics.mean(p[k]) for p in per_scene.values() if k in p]
        pairs = [x for p in per_scene.values() if k in p for x in p[k]]
        m, h = interval(scene_means)
        mp, hp = interval(pairs)
        print(f"| {names[k]} | {len(scene_means)} | {pct(m, h)} ({verdict(m, h)}) | "
              f"{pct(mp, hp)} ({verdict(mp, hp)}) |")
    print()


def versus_simple(d):
    """Per seed, the gate's choices against the better of 3DGS and DropGaussian on this scene
    (the one with the lower mean average error over the seeds: chosen on the held-out views,
    which favours the baseline, not us): {key: [method / simple − 1 per seed]}, and its name."""
    runs = d["runs"]
    simple = [k for k in ("baseline", "drop") if k in runs]
    if not simple:
        return {}, None
    mean = lambda k: statistics.mean(v["avg_error"] for v in runs[k].values())
    best = min(simple, key=mean)
    out = {}
    for k in ("gate", "gate_drop"):
        if k in runs:
            common = sorted(set(runs[k]) & set(runs[best]))
            out[k] = [runs[k][t]["avg_error"] / runs[best][t]["avg_error"] - 1.0 for t in common]
    return out, best


def overall_simple(data):
    names = labels()
    per_scene = {s: versus_simple(d) for s, d in data.items()}
    if not any(v[0] for v in per_scene.values()):
        return
    print("Against the better of 3DGS and DropGaussian per scene (" + ", ".join(
        f"{s}: {names[b]}" for s, (_, b) in per_scene.items() if b) + "):\n")
    print("| method | scenes | mean paired change, over scenes (95 %) | "
          "over (scene, seed) pairs (95 %) |")
    print("|---|---:|---:|---:|")
    for k in ("gate", "gate_drop"):
        scene_means = [statistics.mean(v[0][k]) for v in per_scene.values() if v[0].get(k)]
        pairs = [x for v in per_scene.values() for x in v[0].get(k, [])]
        if not scene_means:
            continue
        m, h = interval(scene_means)
        mp, hp = interval(pairs)
        print(f"| {names[k]} | {len(scene_means)} | {pct(m, h)} ({verdict(m, h)}) | "
              f"{pct(mp, hp)} ({verdict(mp, hp)}) |")
    print()


CACHE = os.environ.get("AUGSPLAT_CACHE", "cache")
# What the gate's "skip" would have spared: the ensemble and both methods with their
# evaluations (DropGaussian's runs of Staged and Dual too).
ENSEMBLE = ("field[", "render[", "render_test[", "aggregate", "eval_ensemble")


def node_seconds(out_dir, scene):
    """{instance name: compute seconds} of a scene's run, from the store's action entries."""
    path = os.path.join(out_dir, f"{scene}.summary.json")
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        nodes = json.load(f)["nodes"]
    out = {}
    for n in nodes:
        entry = os.path.join(CACHE, "actions", n["key"][:2], n["key"] + ".json")
        if os.path.exists(entry):
            with open(entry) as f:
                out[n["name"]] = json.load(f).get("seconds", 0.0)
    return out


def gate_table(out_dir, data):
    """The gate's choice (training views only) against what the held-out views favour (the
    better of Staged and Dual by its mean average error over the seeds when it is more than
    1 % below 3DGS's, else neither), and the compute its choice would have spared."""
    names = labels()
    rows = [(s, d) for s, d in data.items() if d["choice"] is not None]
    if not rows:
        return
    print("| scene | rehearsed 3DGS / Staged / Dual | gate chose | held-out favours | right | "
          "spared s | gate s |")
    print("|---|---|---|---|---|---:|---:|")
    right = 0
    for s, d in rows:
        g, runs = d["evidence"], d["runs"]
        mean = lambda k: statistics.mean(v["avg_error"] for v in runs[k].values())
        best = min(("staged", "dual"), key=lambda k: mean(k) if k in runs else float("inf"))
        favours = best if best in runs and mean(best) / mean("baseline") - 1 <= -0.01 else "baseline"
        right += favours == d["choice"]
        secs = node_seconds(out_dir, s)
        skipped = {"baseline": ("staged", "dual", "eval_staged", "eval_dual") + ENSEMBLE,
                   "staged": ("dual", "eval_dual"), "dual": ("staged", "eval_staged")}[d["choice"]]
        spared = sum(v for k, v in secs.items() if k.startswith(skipped))
        cost = sum(v for k, v in secs.items() if k.startswith("gate"))
        staged = g.get("staged") or {}
        rehearsed = (f"{g['baseline']['error']:.4f} / {staged.get('error', float('nan')):.4f} / "
                     f"{g['method']['error']:.4f}")
        print(f"| {s} | {rehearsed} | {names[d['choice']]} | {names[favours]} | "
              f"{'yes' if favours == d['choice'] else 'no'} | {spared:,.0f} | {cost:,.0f} |")
    print(f"\nThe gate chose as the held-out views favour on {right} of {len(rows)} scenes.\n")


def snapshot(data):
    """The per-scene, per-method, per-seed metrics (for --json / --check)."""
    return {s: {k: {str(seed): {m: v[m] for m in METRICS} for seed, v in sorted(r.items())}
                for k, r in d["runs"].items()} for s, d in data.items()}


def main():
    args = sys.argv[1:]
    check = write = None
    if args[:1] == ["--check"]:
        check, args = args[1], args[2:]
    elif args[:1] == ["--json"]:
        write, args = args[1], args[2:]
    if not args:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    out_dir, scenes = args[0], args[1:]
    data = load(out_dir, scenes)
    if check:
        with open(check) as f:
            want = json.load(f)
        got = json.loads(json.dumps(snapshot(data)))
        if got != want:
            print(f"the study's figures differ from {check}:\n{json.dumps(got, indent=1)}",
                  file=sys.stderr)
            sys.exit(1)
        print(f"the study's figures are those of {check}")
        return
    if write:
        with open(write, "w") as f:
            json.dump(snapshot(data), f, indent=1, sort_keys=True)
            f.write("\n")
    per_scene = {}
    for s in scenes:
        per_scene[s] = scene_table(s, data[s])
    overall(per_scene)
    overall_simple(data)
    gate_table(out_dir, data)


if __name__ == "__main__":
    main()
