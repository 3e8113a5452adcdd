#!/usr/bin/env python3
"""Prints the gate validation table from the runs of validate_gate.sh.

usage: gate_table.py OUT_DIR SCENE...

Per scene: the gate's evidence (rehearsed baseline and Dual errors, its unforced decision),
the held-out average error of 3DGS / Staged / Dual at their best checkpoints, whether the
better method beat the baseline by more than 1 %, and the compute seconds of what the gate
would skip (the ensemble, Staged, Dual and their evaluations) against the gate's own cost.
"""
import json
import os
import sys

CACHE = os.environ.get("AUGSPLAT_CACHE", "cache")
GATED = ("field[", "render[", "render_test[", "aggregate", "eval_ensemble", "staged", "dual",
         "eval_staged", "eval_dual")


def entry(key):
    with open(os.path.join(CACHE, "actions", key[:2], key + ".json")) as f:
        return json.load(f)


def output(key, name):
    return os.path.join(CACHE, "outputs", entry(key)["outputs"][name])


def main():
    out, scenes = sys.argv[1], sys.argv[2:]
    print("| scene | gate: rehearsed 3DGS → Dual | gate says | held-out 3DGS / Staged / Dual "
          "| best method vs 3DGS | method helped (> 1 %) | gate right | skippable s | gate s |")
    print("|---|---|---|---|---|---|---|---:|---:|")
    for s in scenes:
        with open(os.path.join(out, s + ".summary.json")) as f:
            nodes = {n["name"]: n for n in json.load(f)["nodes"]}
        # A later gate-only run (`--target gate`, e.g. after the rehearsal changed) wins.
        gate_node = nodes["gate"]
        later = os.path.join(out, s + "_gate.summary.json")
        if os.path.exists(later):
            with open(later) as f:
                gate_nodes = {n["name"]: n for n in json.load(f)["nodes"]}
            gate_node = gate_nodes["gate"]
            nodes.update({k: v for k, v in gate_nodes.items() if k.startswith("gate")})
        outs = entry(gate_node["key"])["outputs"]
        if "evidence" in outs:
            path = os.path.join(CACHE, "outputs", outs["evidence"], "gate_evidence.json")
        else:  # before the decision and its evidence were split
            path = os.path.join(CACHE, "outputs", outs["decision"], "gate.json")
        with open(path) as f:
            g = json.load(f)
        errs = {}
        for m in ("baseline", "staged", "dual"):
            with open(os.path.join(output(nodes["eval_" + m]["key"], "eval"), "metrics.json")) as f:
                e = json.load(f)
            errs[m] = e["mean"].get("avg_error") or e["mean"]["mse"]
        best = min(errs["staged"], errs["dual"])
        rel = best / errs["baseline"] - 1.0
        helped = rel <= -0.01
        secs = lambda pred: sum(entry(n["key"])["seconds"] for name, n in nodes.items() if pred(name))
        skippable = secs(lambda n: n.startswith(GATED))
        gate = secs(lambda n: n.startswith("gate"))
        print(f"| {s} | {g['metric']} {g['baseline']['error']:.4f} → {g['method']['error']:.4f} "
              f"({100 * g['method']['relative']:+.1f} %) | {'run' if g['evidence_run'] else 'skip'} "
              f"| {errs['baseline']:.4f} / {errs['staged']:.4f} / {errs['dual']:.4f} "
              f"| {100 * rel:+.1f} % | {'yes' if helped else 'no'} "
              f"| {'yes' if helped == g['evidence_run'] else 'no'} | {skippable:.0f} | {gate:.0f} |")


if __name__ == "__main__":
    main()
