"""Paired comparison of camera-benchmark runs: candidate minus base on the same draw.

``bench_tracker.py real --json F`` writes each run's tracking figures unrounded, with every
velocity row keyed (sequence, frame, car, accelerating). A rule that judges a change over several
draws of the detections (``--seed-offset``) compares each candidate run with the base run of
the same draw, then averages the differences over the draws. The velocity is also compared like
for like: the RMSE of both runs over the rows both matched (a change that matches more cars
adds rows, harder ones, and moves the plain RMSE for that reason alone).

    python bench/paired.py --base b0.json b1.json b2.json --cand c0.json c1.json c2.json

The i-th base file pairs with the i-th candidate file. Prints, per benchmark section and
filter, every figure's mean paired difference and its range over the draws, and the
like-for-like velocity (all rows, accelerating rows) of base and candidate.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2))) if len(e) else math.nan


def like_for_like(base_rows: list, cand_rows: list) -> dict:
    """RMSE [m/s] of base and candidate over the keyed velocity rows both have: every row
    (``all``) and the accelerating or braking cars' (``accelerating``); ``n`` rows each."""
    b = {(r[0], r[1], r[2]): (r[3], r[4]) for r in base_rows}
    c = {(r[0], r[1], r[2]): (r[3], r[4]) for r in cand_rows}
    common = sorted(set(b) & set(c))
    out = {}
    for name, keep in (("all", lambda k: True), ("accelerating", lambda k: b[k][0] == 1)):
        keys = [k for k in common if keep(k)]
        eb = np.array([b[k][1] for k in keys], float)
        ec = np.array([c[k][1] for k in keys], float)
        out[name] = {"n": len(keys), "base": _rms(eb), "cand": _rms(ec)}
    return out


def paired(base: list[dict], cand: list[dict]) -> dict:
    """{section: {filter: {figure: [differences per draw]}}} plus like-for-like rows."""
    out: dict = {}
    for b, c in zip(base, cand, strict=True):
        for section in sorted(set(b) & set(c)):
            for flt in sorted(set(b[section]) & set(c[section])):
                fb, fc = b[section][flt], c[section][flt]
                slot = out.setdefault(section, {}).setdefault(flt, {})
                for key in fb:  # the scalar figures (row lists are compared below or not)
                    if key not in fc or isinstance(fb[key], (list, dict)):
                        continue
                    slot.setdefault(key, []).append(float(fc[key]) - float(fb[key]))
                if "velocity_rows_keyed" in fb and "velocity_rows_keyed" in fc:
                    lfl = like_for_like(fb["velocity_rows_keyed"], fc["velocity_rows_keyed"])
                    for name, r in lfl.items():
                        slot.setdefault(f"lfl_{name}_base", []).append(r["base"])
                        slot.setdefault(f"lfl_{name}_cand", []).append(r["cand"])
                        slot.setdefault(f"lfl_{name}_diff", []).append(r["cand"] - r["base"])
                        slot.setdefault(f"lfl_{name}_rows", []).append(r["n"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", nargs="+", required=True, help="base runs' --json files")
    ap.add_argument("--cand", nargs="+", required=True, help="candidate runs', same order")
    args = ap.parse_args(argv)
    if len(args.base) != len(args.cand):
        print(
            f"error: --base has {len(args.base)} files, --cand {len(args.cand)}: "
            "one candidate per base run (the same draw)",
            file=sys.stderr,
        )
        return 2
    runs = []
    for f in args.base + args.cand:
        try:
            runs.append(json.loads(Path(f).read_text()))
        except (OSError, ValueError) as exc:
            print(f"error: {f}: {exc}", file=sys.stderr)
            return 2
    n = len(args.base)
    res = paired(runs[:n], runs[n:])
    for section, flts in res.items():
        for flt, figs in flts.items():
            print(f"{section} / {flt}: mean over {n} draw(s) (candidate - base unless named)")
            for key, vals in figs.items():
                v = np.array(vals, float)
                print(
                    f"  {key:28s} {np.nanmean(v):+10.4f}   draws "
                    + " ".join(f"{x:+.4f}" for x in v)
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
