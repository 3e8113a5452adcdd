#!/usr/bin/env python3
"""Prints the gate validation table from the runs of validate_gate.sh.

usage: gate_table.py OUT_DIR SCENE...

Per scene: the gate's evidence (rehearsed baseline, Staged and Dual errors; its unforced
decision: run Staged, run Dual or skip — a gate of `criterion: Method` rehearses Dual alone
and says run or skip), the held-out average error of 3DGS / Staged / Dual at their best
checkpoints, which method the held-out views favour (the better of Staged and Dual when it is
more than 1 % below 3DGS, else neither), whether the gate chose the same, the held-out change
of what the gate chose against 3DGS, and the compute seconds of what the gate would skip (the
ensemble, Staged, Dual and their evaluations) against the gate's own cost.
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
    print("| scene | gate: rehearsed 3DGS → Staged / Dual | gate says | held-out 3DGS / Staged / Dual "
          "| held-out favours | gate right | gate's choice vs 3DGS | skippable s | gate s |")
    print("|---|---|---|---|---|---|---:|---:|---:|")
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
        best = "staged" if errs["staged"] <= errs["dual"] else "dual"
        favoured = best if errs[best] / errs["baseline"] - 1.0 <= -0.01 else None
        chosen = (g.get("chosen") or "dual").lower() if g["evidence_run"] else None
        if g["criterion"] == "Method" and chosen:
            # A Dual-only gate says run for both methods: right when either helps.
            right = favoured is not None
        else:
            right = chosen == favoured
        change = errs[chosen] / errs["baseline"] - 1.0 if chosen else 0.0
        secs = lambda pred: sum(entry(n["key"])["seconds"] for name, n in nodes.items() if pred(name))
        skippable = secs(lambda n: n.startswith(GATED))
        gate = secs(lambda n: n.startswith("gate"))
        staged = g.get("staged")
        rehearsed = (f"{g['baseline']['error']:.4f} → "
                     + (f"{staged['error']:.4f} ({100 * staged['relative']:+.1f} %) / " if staged else "— / ")
                     + f"{g['method']['error']:.4f} ({100 * g['method']['relative']:+.1f} %)")
        says = f"run {chosen.capitalize()}" if chosen else "skip"
        if g["criterion"] == "Method" and chosen:
            says = "run"
        print(f"| {s} | {g['metric']} {rehearsed} | {says} "
              f"| {errs['baseline']:.4f} / {errs['staged']:.4f} / {errs['dual']:.4f} "
              f"| {favoured.capitalize() if favoured else 'neither'} | {'yes' if right else 'no'} "
              f"| {100 * change:+.1f} % | {skippable:.0f} | {gate:.0f} |")

if __name__ == "__main__":
    main()
