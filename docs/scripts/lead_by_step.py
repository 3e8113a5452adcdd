#!/usr/bin/env python3
"""A method's held-out average error against a baseline's, step by step, seed-matched.

    python3 docs/scripts/lead_by_step.py SCENE METHOD_EVAL BASELINE_EVAL [METHOD_EVAL BASELINE_EVAL]...

Each *_EVAL is the `eval` folder of an `Evaluate` output (`augsplat run … --out DIR` writes
DIR/eval_dual@…/eval), whose `curve.json` holds the held-out evaluation at every
`eval_every` steps of that training. Give one pair per seed (method first). Prints one
Markdown row: the change of the method's average error against the baseline's at steps 300,
600, 1,000, 1,500, 2,000 and the last step, as the mean over the pairs (each pair's change
first, then averaged), with the range over the pairs beside it.
"""
import json
import os
import sys

STEPS = [300, 600, 1000, 1500, 2000]


def curve(folder):
    path = os.path.join(folder, "curve.json")
    with open(path) as f:
        points = json.load(f)["points"]
    if not points:
        sys.exit(f"{path}: no evaluation points")
    return {p["step"]: p["avg_error"] for p in points}


def main():
    args = sys.argv[1:]
    if len(args) < 3 or len(args) % 2 == 0:
        sys.exit(__doc__)
    scene, folders = args[0], args[1:]
    pairs = [(curve(folders[i]), curve(folders[i + 1])) for i in range(0, len(folders), 2)]
    last = min(max(m) for m, b in pairs)
    cells = []
    for step in STEPS + [last]:
        changes = []
        for m, b in pairs:
            if step not in m or step not in b:
                sys.exit(f"step {step} is missing from a curve: give evaluations every 100 steps")
            changes.append(100.0 * (m[step] / b[step] - 1.0))
        mean = sum(changes) / len(changes)
        cell = f"{mean:+.1f} % ({min(changes):+.0f}…{max(changes):+.0f})"
        cells.append(cell.replace("-", "−"))
    header = " | ".join(f"{s:,}" for s in STEPS + [last])
    print(f"| scene, pairs | {header} |", file=sys.stderr)
    print(f"| {scene}, {len(pairs)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
