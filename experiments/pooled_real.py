"""Pooled test on the real Cusick scans: does one candidate effect help across fabrics?

Each fabric alone fits its capture to about the noise, so no single diagnosis can act on a
residual that all fabrics share (the skirt band heights, ``diagnose_real.py``: the scans hang
2–7 mm below the fitted drapes on 9 of 10 fabrics outside the floor). Here every fabric group
(all captures of fabric NN, the first fitted) gets the baseline fit and, for each candidate, the
nested refit with the effect added (``select.nested_refit``, as ``select.search(screen=None)``
refits: continuation from the baseline's rest state, the effect free from null). The held-out misfit change of each
fabric (½χ², the selection rows on the other captures) is then pooled: under "nothing missing"
a nested refit only fits the fitted capture's noise, so it does not lower the held-out misfit
on average; a shared missing effect lowers it on most fabrics. One JSON line per fabric and
candidate, then a summary per candidate (gains, fitted-θ signs, sign and t tests).

The control (``--make-control DIR``, then ``--data DIR``): virtual-lab groups named like the
real scans, made by the base model alone (no effect) on a finer mesh (10 mm graded from 2 mm,
which reproduces uniform 5 mm fits within 7 %), warp angle and density unknown as in the scans.
A gain there is what the fit mesh and the fitted family lack, not what the fabrics do.

The shared test (``--shared-from`` an earlier run's lines): each group is refitted with the effect
held at the median θ the earlier run fitted to the *other* groups (only k1 free), a one-parameter
model shared by all fabrics whose value each group did not choose; groups the earlier run did not
see (a control) get the median over all of its groups. ``--compare`` a control run's
lines tests that the gains exceed the control's (one-sided Mann–Whitney). ``--hold θ`` holds the
effect at one value fixed in advance in every group instead (the same held refit).

Usage: python -m experiments.pooled_real [--candidates bending_saturation,heavy_hem] [--only f01,f02]
       [--spacing 0.02] [--rim 0.003] [--max-steps 6] [--out pooled.jsonl] [--data DIR]
       [--shared-from FREE.jsonl | --hold THETA] [--compare CONTROL.jsonl]
       python -m experiments.pooled_real --summary-of RUN.jsonl [--compare CONTROL.jsonl]
       python -m experiments.pooled_real --make-control DIR [--control-fabrics 4] [--control-from 0] [--captures 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np
from scipy import stats

from drapejax import refine
from drapejax.diagnose import NoiseFloor, initial_params
from drapejax.diagnose.select import SELECTION_KEYS, evaluate_baseline, held_refit, nested_refit
from drapejax.effects import REGISTRY
from drapejax.inverse.prior import default_prior
from drapejax.io import load_measurement
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import make_measurement

if __package__:  # python -m experiments.pooled_real
    from .common import emit, groups, read
else:  # python experiments/pooled_real.py
    from common import emit, groups, read

jax.config.update("jax_enable_x64", True)


def shared_thetas(path: Path) -> dict[str, dict[str, list[float]]]:
    """Per effect and group: the median θ that an earlier run (its JSON lines) fitted to the *other*
    groups, so the value a group is tested with owes nothing to that group's captures; under "*"
    the median over all its groups, for groups it did not see (a control)."""
    rows = read_rows(path)
    out: dict[str, dict[str, list[float]]] = {}
    for name in sorted({r["effect"] for r in rows}):
        th = {r["group"]: np.asarray(r["theta"], float) for r in rows if r["effect"] == name}
        out[name] = {g: np.median([v for h, v in th.items() if h != g], axis=0).tolist() for g in th}
        out[name]["*"] = np.median(list(th.values()), axis=0).tolist()
    return out


def _mean_errors(trial) -> dict:
    """The error-ratio keys (``select.SELECTION_KEYS``) averaged over the held-out captures."""
    return {k: float(np.mean([e[k] for e in trial.heldout])) for k in SELECTION_KEYS}


def fabric_rows(folders: list[Path], candidates: list, args, shared: dict | None = None) -> list[dict]:
    """Baseline and nested refits of one fabric group; held-out misfits and error ratios of each.

    With ``shared`` (``shared_thetas``, keyed by this group) each effect is held at that value
    and only the k1 are refitted; else the effect is free from null."""
    ms = [load_measurement(f) for f in folders]
    floor = NoiseFloor.from_captures(ms)
    init = initial_params(ms[0])
    mesh = cusick_mesh(args.spacing, warp_angle_deg=ms[0].warp_angle_deg or 0.0, rim_spacing_m=args.rim)
    base_fit = refine.fit(ms[0], init=init, spacing_m=args.spacing, max_steps=args.max_steps, mesh=mesh)
    base = evaluate_baseline(ms, base_fit, mesh, floor)
    rows = []
    for eff in candidates:
        t0 = time.perf_counter()
        held = None if shared is None else shared[eff.name]
        if held is None:
            res = nested_refit(ms[0], base_fit, [eff], init=init, mesh=mesh, spacing_m=args.spacing,
                               max_steps=args.max_steps, config=refine.CONTINUATION_CONFIG)
        else:
            res = held_refit(ms[0], base_fit, [eff], held, init=init, mesh=mesh, spacing_m=args.spacing,
                             max_steps=args.max_steps, config=refine.CONTINUATION_CONFIG)
        tr = evaluate_baseline(ms, res, mesh, floor)
        rows.append({"effect": eff.name, "theta": np.asarray(res.theta[3:]).tolist(), "held": held,
                     "status": res.status,
                     "fit_loss": [base_fit.loss, res.loss], "heldout_misfit": [float(np.mean(base.heldout_loss)),
                                                                              float(np.mean(tr.heldout_loss))],
                     "error_ratio": [base.error_ratio, tr.error_ratio],
                     "heldout_error": [_mean_errors(base), _mean_errors(tr)],
                     "k1_log_scale": [np.asarray(base_fit.theta[:3]).tolist(), np.asarray(res.theta[:3]).tolist()],
                     "within_floor": base.within_noise,
                     "n_rows": base.n_rows, "seconds": time.perf_counter() - t0})
    return rows


def make_control(out: Path, fabrics: int, captures: int, first: int = 0) -> None:
    """Base-model groups ``bdp_f{90+N}_sample_1_capture_C``, N = ``first`` … ``fabrics`` − 1: "mid",
    "heavy", then prior draws (seed 0; a longer draw keeps the shorter one's members). Captures
    already on disk are kept, so a larger control extends a smaller one."""
    n_drawn = max(fabrics - 2, 0)
    drawn = default_prior().sample(n_drawn, 0)
    members = [example_params("mid"), example_params("heavy")] + [jax.tree.map(lambda a: a[i], drawn)
                                                                  for i in range(n_drawn)]
    for f, params in list(enumerate(members[:fabrics]))[first:]:
        for c in range(1, captures + 1):
            if (out / f"bdp_f{90 + f}_sample_1_capture_{c}" / "measurement.json").is_file():
                continue
            make_measurement(out / f"bdp_f{90 + f}_sample_1_capture_{c}", params=params, spacing_m=0.01,
                             rim_spacing_m=0.002, seed=c, warp_angle_deg=None, density_known=False)
            print(f"# control f{90 + f} capture {c}", file=sys.stderr, flush=True)


def summary(rows: list[dict]) -> dict:
    """Per candidate over the fabrics: held-out misfit gains (before − after), how many are
    positive, the sign test and a one-sided paired t test that the mean gain is > 0, the error
    ratio's gains (on how many groups it rises, and the sign test that it rises on more than half),
    and the signs of the fitted θ (first component)."""
    out = {}
    for name in sorted({r["effect"] for r in rows}):
        rs = [r for r in rows if r["effect"] == name]
        gain = np.array([r["heldout_misfit"][0] - r["heldout_misfit"][1] for r in rs])
        ratio = np.array([r["error_ratio"][0] - r["error_ratio"][1] for r in rs])
        th = np.array([r["theta"][0] for r in rs])
        pos = int(np.sum(gain > 0))
        sign_p = stats.binomtest(pos, len(rs), alternative="greater").pvalue
        t_p = stats.ttest_1samp(gain, 0.0, alternative="greater").pvalue if len(rs) > 1 else None
        out[name] = {"fabrics": len(rs), "heldout_gain": gain.round(3).tolist(), "gain_sum": float(gain.sum()),
                     "gain_positive": pos, "sign_test_p": float(sign_p),
                     "t_test_p": None if t_p is None else float(t_p),
                     "error_ratio_gain": ratio.round(3).tolist(), "error_ratio_rises": int(np.sum(ratio < 0)),
                     "error_ratio_rise_p": float(stats.binomtest(int(np.sum(ratio < 0)), len(rs),
                                                                 alternative="greater").pvalue),
                     "theta": th.round(3).tolist(),
                     "theta_positive": int(np.sum(th > 0)), "theta_negative": int(np.sum(th < 0))}
    return out


def read_rows(path: Path) -> list[dict]:
    """The per-group lines of an earlier run (its summary line left out)."""
    return [r for r in read(path) if "effect" in r]


ALPHA = 0.05
"""Level of each test of the pooled verdict (``compared``)."""


def compared(out: dict, control: Path | None) -> dict:
    """``summary`` with, per effect the control run also tested, its gains and a one-sided
    Mann–Whitney p that the gains here are larger; then the pooled verdict ``shared_effect``:
    the gains are positive on more groups than chance allows (sign test) and, where a control
    was given, larger than the control's, and the error ratio does not rise on more groups than
    chance allows (the pooled form of ``select.ratio_rises``, the veto of ``diagnose``), all at
    ``ALPHA``; ``verdict`` says which test decided."""
    if control is not None:
        control_gain = summary(read_rows(control))
        for name, s in out.items():
            if name in control_gain:
                c = control_gain[name]["heldout_gain"]
                s["control_gain"] = c
                s["mann_whitney_p"] = float(stats.mannwhitneyu(s["heldout_gain"], c, alternative="greater").pvalue)
    for s in out.values():
        tests = [("held-out misfit gain (sign test)", s["sign_test_p"] < ALPHA),
                 ("gain above the control's (Mann-Whitney)", s.get("mann_whitney_p", 0.0) < ALPHA),
                 (f"error ratio does not rise (it rises on {s['error_ratio_rises']} of {s['fabrics']})",
                  s["error_ratio_rise_p"] >= ALPHA)]
        failed = [label for label, ok in tests if not ok]
        s["shared_effect"] = not failed
        s["verdict"] = "all tests pass" if not failed else "refused: " + "; ".join(failed)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / "../shared/data/real_cusick")
    ap.add_argument("--candidates", default="bending_saturation,heavy_hem")
    ap.add_argument("--only", default="", help="comma-separated fabric ids (e.g. f01,f02)")
    ap.add_argument("--spacing", type=float, default=refine.FIT_SPACING_M)
    ap.add_argument("--rim", type=float, default=refine.FIT_RIM_SPACING_M)
    ap.add_argument("--max-steps", type=int, default=6)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--make-control", type=Path, default=None, help="write the control groups here and stop")
    ap.add_argument("--control-fabrics", type=int, default=4)
    ap.add_argument("--control-from", type=int, default=0, help="first control group to make (0-based)")
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--shared-from", type=Path, default=None,
                    help="an earlier run's lines: hold each effect at the other groups' median θ")
    ap.add_argument("--hold", type=float, nargs="+", default=None,
                    help="hold the effect at this θ in every group (a value fixed in advance; one candidate)")
    ap.add_argument("--compare", type=Path, default=None,
                    help="a control run's lines: test that the gains here exceed the control's (Mann-Whitney)")
    ap.add_argument("--summary-of", type=Path, default=None,
                    help="print the summary of an earlier run's lines and stop")
    args = ap.parse_args()
    if args.summary_of is not None:
        emit({"summary": compared(summary(read_rows(args.summary_of)), args.compare)}, args.out)
        return
    if args.make_control is not None:
        make_control(args.make_control, args.control_fabrics, args.captures, args.control_from)
        return
    candidates = [REGISTRY[n] for n in args.candidates.split(",") if n]
    only = {f.strip() for f in args.only.split(",") if f.strip()}
    if args.hold is not None and (args.shared_from is not None or len(candidates) != 1):
        raise SystemExit("--hold: one candidate, and not with --shared-from")
    shared = None if args.shared_from is None else shared_thetas(args.shared_from)
    if args.hold is not None:
        shared = {candidates[0].name: {"*": list(args.hold)}}
    if shared is not None and (missing := [e.name for e in candidates if e.name not in shared]):
        raise SystemExit(f"{args.shared_from}: no θ for {missing}")
    rows = []
    for key, folders in groups(args.data.resolve()).items():
        if only and key not in only or len(folders) < 2:
            continue
        t0 = time.perf_counter()
        held = None if shared is None else {n: v.get(key, v["*"]) for n, v in shared.items()}
        for r in fabric_rows(folders, candidates, args, held):
            r = {"group": key, "captures": len(folders), **r}
            rows.append(r)
            emit(r, args.out)
        print(f"# {key}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    emit({"summary": compared(summary(rows), args.compare)}, args.out)


if __name__ == "__main__":
    main()
