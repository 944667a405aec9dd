#!/usr/bin/python3
"""Scores a diagnosis benchmark directory written by generate.py (generator 2) after run.sh:
per effect precision, recall and F1 over the seven effects, macro-F1, false alarms on the
clean and the uniform-shift controls, the held-out gain of every accepted effect, and the time
per case. Reads DIR/labels/case_XXX.json and DIR/case_XXX/diagnosis.json.

    python3 scripts/bench/gen2/score.py DIR [--report NAME]

--report NAME scores case_XXX/NAME.json instead of diagnosis.json (a replay written by
examples/catalogue_replay).
"""
import glob
import json
import os
import sys

EFFECTS = ["non_rayleigh_damping", "beating_pair", "support_contact", "contact_duration",
           "reverb_noise", "pitch_glide", "added_mass"]


def main(d, report="diagnosis"):
    rows = []
    for lab in sorted(glob.glob(os.path.join(d, "labels", "case_*.json"))):
        case = os.path.splitext(os.path.basename(lab))[0]
        truth = json.load(open(lab))
        rep = os.path.join(d, case, report + ".json")
        if not os.path.exists(rep):
            rows.append((case, truth, None, None, None))
            continue
        r = json.load(open(rep))
        acc = r["catalogue"]["accepted"]
        names = [a["name"] for a in acc if a["name"] in EFFECTS]
        gains = [(a["name"], a.get("held_out_before"), a.get("held_out_after")) for a in acc]
        secs = None
        try:
            secs = float(open(os.path.join(d, case, "seconds")).read())
        except OSError:
            pass
        rows.append((case, truth, names, gains, secs))
    tp = {e: 0 for e in EFFECTS}
    fp = dict(tp)
    fn = dict(tp)
    print("| case | object | mics | response | truth | accepted | held-out before -> after | s |")
    print("|---|---|---|---|---|---|---|---|")
    failed = 0
    for case, truth, names, gains, secs in rows:
        t = truth["effects"]
        label = ",".join(t) or truth["control"]
        if names is None:
            failed += 1
            print(f"| {case} | {truth['object']} | {truth['microphones']} | {truth['response']} | {label} | FAILED | | |")
            for e in t:
                fn[e] += 1
            continue
        for e in EFFECTS:
            if e in t and e in names:
                tp[e] += 1
            elif e in names:
                fp[e] += 1
            elif e in t:
                fn[e] += 1
        ho = "; ".join(f"{n} {b:.3g}->{a:.3g}" if b is not None and a is not None else n for n, b, a in gains)
        print(f"| {case} | {truth['object']} | {truth['microphones']} | {truth['response']} | {label} | {','.join(names) or '-'} | {ho} | {secs if secs is not None else ''} |")
    print()
    print("| effect | TP | FP | FN | precision | recall | F1 |")
    print("|---|---|---|---|---|---|---|")
    f1s = []
    for e in EFFECTS:
        p = tp[e] / (tp[e] + fp[e]) if tp[e] + fp[e] else (1.0 if fn[e] == 0 else 0.0)
        rc = tp[e] / (tp[e] + fn[e]) if tp[e] + fn[e] else 1.0
        f1 = 2 * p * rc / (p + rc) if p + rc else 0.0
        f1s.append(f1)
        print(f"| {e} | {tp[e]} | {fp[e]} | {fn[e]} | {p:.2f} | {rc:.2f} | {f1:.2f} |")
    print(f"\nmacro-F1 {sum(f1s) / len(f1s):.3f} over {len(EFFECTS)} effects")
    for control in ("clean", "uniform_shift"):
        sel = [r for r in rows if r[1]["control"] == control and r[2] is not None]
        alarms = sum(1 for r in sel if r[2])
        print(f"{control}: {alarms} of {len(sel)} with an effect claimed")
    held = [(b, a) for r in rows if r[3] for n, b, a in r[3] if b is not None and a is not None]
    worse = sum(1 for b, a in held if a >= b)
    print(f"accepted effects with a held-out error: {len(held)}, of which not lowering it: {worse}")
    secs = [r[4] for r in rows if r[4] is not None]
    if secs:
        print(f"time per case: median {sorted(secs)[len(secs) // 2]:.0f} s, max {max(secs):.0f} s")
    print(f"runs that failed: {failed}")


if __name__ == "__main__":
    args = sys.argv[1:]
    report = "diagnosis"
    if "--report" in args:
        i = args.index("--report")
        report = args[i + 1]
        del args[i:i + 2]
    main(args[0], report)
