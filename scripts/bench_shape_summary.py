#!/usr/bin/env python3
"""Summary of the shape benchmark's JSON files (scripts/bench_shape.sh): per task and rank count,
the absolute error per shape (the answer and the finest level alone), and per grid level the mean
time of one evaluation split into meshing / assembly / eigen-solve / gradient, the evaluations per
fit, and the total time per fit and per task. Prints markdown.

    python3 scripts/bench_shape_summary.py out/bench_shape/*.json
"""
import json
import re
import sys
from collections import defaultdict


def main(paths):
    for path in paths:
        with open(path) as f:
            records = json.load(f)
        m = re.search(r"(thickness|morph)_np(\d+)", path)
        task, ranks = (m.group(1), m.group(2)) if m else (path, "?")
        print(f"\n### {task}, {ranks} rank(s) ({path})\n")
        by_shape = defaultdict(list)
        for r in records:
            fit = r["fit"]
            # The finest level's answer: the mean over the replicas of the finest spacing.
            finest_cells = max(l["cells"] for l in fit["levels"])
            finest = [l["parameter"] for l in fit["levels"] if l["cells"] == finest_cells]
            line = fit.get("extrapolated")
            by_shape[r["shape"]].append((abs(fit["parameter"] - r["truth"]), abs(sum(finest) / len(finest) - r["truth"]), None if line is None else abs(line - r["truth"]), fit["seconds"]))
        print("| shape | fits | mean abs error | max abs error | mean abs error, finest level (mean of its replicas) | mean abs error, line | mean fit s | max fit s |")
        print("|---|---|---|---|---|---|---|---|")
        for shape, rows in by_shape.items():
            e = [x[0] for x in rows]
            f = [x[1] for x in rows]
            l = [x[2] for x in rows if x[2] is not None]
            s = [x[3] for x in rows]
            line = f"{sum(l) / len(l):.4f}" if l else "–"
            print(f"| {shape} | {len(rows)} | {sum(e) / len(e):.4f} | {max(e):.4f} | {sum(f) / len(f):.4f} | {line} | {sum(s) / len(s):.0f} | {max(s):.0f} |")
        levels = defaultdict(lambda: defaultdict(float))
        for r in records:
            fit = r["fit"]
            for e in fit["history"]:
                if e["failure"] is not None:
                    levels[e["cells"]]["failed"] += 1
                    continue
                lv = levels[e["cells"]]
                lv["n"] += 1
                for k in ("meshing", "assembly", "solve", "gradient"):
                    lv[k] += e["timings"][k]
                lv["tets"] += e["tets"]
                lv["p2"] += e["p2_nodes"]
        fits = len(records)
        total = sum(r["fit"]["seconds"] for r in records)
        print("\n| level (cells) | evaluations per fit (all replicas) | mean tets | mean P2 nodes | meshing s | assembly s | solve s | gradient s | s per evaluation | failed evaluations |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for cells in sorted(levels):
            lv = levels[cells]
            n = max(lv["n"], 1)
            per = [lv[k] / n for k in ("meshing", "assembly", "solve", "gradient")]
            print(f"| {cells} | {lv['n'] / fits:.1f} | {lv['tets'] / n:.0f} | {lv['p2'] / n:.0f} | {per[0]:.3f} | {per[1]:.2f} | {per[2]:.2f} | {per[3]:.3f} | {sum(per):.2f} | {int(lv['failed'])} |")
        print(f"\n{fits} fits, {total:.0f} s of fitting in all ({total / max(fits, 1):.0f} s per fit); targets not included.")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
