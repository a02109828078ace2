"""Diagnosis loop (fit → residual → effect search → refit) on every real Cusick scan.

Captures are diagnosed in groups (``--group fabric``, the default: every capture of fabric NN,
since most specimens in the set were captured once; ``--group specimen``: captures
``bdp_fNN_sample_S_capture_C`` with equal NN and S). The first capture of a group is fitted, the
others are held out and set the capture-to-capture noise floor. Prints one JSON line per
group: folders, baseline error, residual signature, effects tested, effect selected (or none),
final error, each model's expected held-out error over fresh drops, the noise floor and whether
the residual is within it; a summary line at the end.
The summary also tests each radial band's mean height residual for a sign shared across the
groups outside the floor (two-sided sign test): a bias too small to act on in one fit but
systematic over many fabrics. Slow: with the fresh-drop screen (the default of ``diagnose``) a
screened step takes 12–16 minutes on the 25 mm virtual lab on two CPU cores; ``--summarise FILE`` prints the summary of
recorded lines without fitting anything.

Usage: python -m experiments.diagnose_real [--data ../shared/data/real_cusick] [--spacing 0.025] [--rim 0.003]
       [--group fabric|specimen] [--limit N] [--only f11,f12] [--no-effects] [--candidates bending_saturation]
       [--reports DIR] [--out results.jsonl]
       python -m experiments.diagnose_real --summarise results.jsonl
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
from scipy import stats

from drapejax.diagnose import diagnose
from drapejax.effects import REGISTRY

if __package__:  # python -m experiments.diagnose_real
    from .common import emit, groups, read
else:  # python experiments/diagnose_real.py
    from common import emit, groups, read

jax.config.update("jax_enable_x64", True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / "../shared/data/real_cusick")
    ap.add_argument("--spacing", type=float, default=0.025)
    ap.add_argument("--rim", type=float, default=None, help="rim spacing of a graded fit mesh, m (default: uniform)")
    ap.add_argument("--buckling", action="store_true",
                    help="cap the base membrane's compression at the element scale (drapejax.energy.Membrane)")
    ap.add_argument("--group", choices=("fabric", "specimen"), default="fabric")
    ap.add_argument("--limit", type=int, default=None, help="diagnose at most this many groups")
    ap.add_argument("--only", default="", help="comma-separated fabric ids (e.g. f11,f12)")
    ap.add_argument("--max-steps", type=int, default=6, help="optimiser steps of each fit (not effects)")
    ap.add_argument("--max-effects", type=int, default=2, help="largest number of effects combined")
    ap.add_argument("--max-refits", type=int, default=None, help="candidates refitted per step (default: all)")
    ap.add_argument("--no-effects", action="store_true", help="baseline fit and residual analysis only")
    ap.add_argument("--candidates", default="", help="comma-separated effect names (default: the whole library)")
    ap.add_argument("--reports", type=Path, default=None, help="write one HTML report per group here")
    ap.add_argument("--out", type=Path, default=None, help="append the JSON lines to this file")
    ap.add_argument("--summarise", type=Path, default=None, help="print the summary of these recorded lines and stop")
    args = ap.parse_args()
    chosen = [REGISTRY[n] for n in args.candidates.split(",") if n] or None
    if args.summarise is not None:
        print(json.dumps({"summary": summary([r for r in read(args.summarise) if "group" in r])}))
        return
    only = {f.strip() for f in args.only.split(",") if f.strip()}
    todo = [(k, v) for k, v in groups(args.data.resolve(), args.group).items() if not only or k.split("_")[0] in only]
    todo.sort(key=lambda kv: -len(kv[1]))
    if args.limit is not None:
        todo = todo[: args.limit]
    rows = []
    for key, folders in todo:
        t0 = time.perf_counter()
        rep = None if args.reports is None else args.reports / f"{key}.html"
        try:
            r = diagnose(folders, report=rep, spacing_m=args.spacing, rim_spacing_m=args.rim, max_steps=args.max_steps,
                         max_effects=args.max_effects, max_refits=args.max_refits,
                         candidates=[] if args.no_effects else chosen, buckling=args.buckling)
            row = {"group": key, "folders": [f.name for f in folders], "mesh": r["mesh"],
                   "baseline": r["baseline"]["error"],
                   "baseline_heldout": r["baseline"]["heldout_error"], "selected": r["selected"],
                   "selected_values": r["selected_values"], "final": r["final"]["error"],
                   "final_heldout": r["final"]["heldout_error"], "baseline_loss": r["baseline"]["loss"],
                   "final_loss": r["final"]["loss"], "baseline_expected": r["baseline"]["expected"],
                   "final_expected": r["final"]["expected"], "within_noise_floor": r["within_noise_floor"],
                   "baseline_within_noise_floor": r["baseline_within_noise_floor"], "noise_floor": r["noise_floor"],
                   "symmetry": r["residual"]["symmetry"], "bands": r["residual"]["bands"],
                   "tested": [{k: t.get(k) for k in ("name", "with", "signature", "screen_loss", "screen_null_loss",
                                                     "error_ratio", "accepted", "reason")}
                              for t in r["effects_tested"]], "reason": r["reason"]}
        except Exception as e:  # one failing group must not stop the study: record it
            row = {"group": key, "folders": [f.name for f in folders], "error": f"{type(e).__name__}: {e}"}
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        emit(row, args.out)
    print(json.dumps({"summary": summary(rows)}))


def band_sign_tests(done: list[dict]) -> dict:
    """Per radial band, over the groups outside the floor: how many have a negative (scan below
    the fit) and a positive mean height residual, the median, and the two-sided sign-test p."""
    out = {}
    outside = [r for r in done if not r["baseline_within_noise_floor"]]
    for band in sorted({b for r in outside for b in r["bands"]}):
        h = [r["bands"][band]["height_mm"] for r in outside if "height_mm" in r["bands"].get(band, {})]
        neg, pos = sum(v < 0 for v in h), sum(v > 0 for v in h)
        out[band] = {"negative": neg, "positive": pos, "median_mm": float(statistics.median(h)) if h else None,
                     "sign_test_p": float(stats.binomtest(neg, neg + pos).pvalue) if neg + pos else None}
    return out


def summary(rows: list[dict]) -> dict:
    done = [r for r in rows if "error" not in r]
    return {
        "groups": len(rows), "failed": len(rows) - len(done),
        "baseline_within_noise_floor": sum(r["baseline_within_noise_floor"] for r in done),
        "final_within_noise_floor": sum(r["within_noise_floor"] for r in done),
        "selected": {k: sum(k in r["selected"] for r in done)
                     for k in sorted({s for r in done for s in r["selected"]})},
        "none_selected": sum(not r["selected"] for r in done),
        "band_height_sign": band_sign_tests(done)}


if __name__ == "__main__":
    main()
