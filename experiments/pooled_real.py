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

Usage: python experiments/pooled_real.py [--candidates bending_saturation,heavy_hem] [--only f01,f02]
       [--spacing 0.02] [--rim 0.003] [--max-steps 6] [--out pooled.jsonl] [--data DIR]
       python experiments/pooled_real.py --make-control DIR [--control-fabrics 4] [--captures 3]
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
from drapejax.diagnose.select import evaluate_baseline, nested_refit
from drapejax.effects import REGISTRY
from drapejax.inverse.prior import default_prior
from drapejax.io import load_measurement
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import make_measurement

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_real import groups  # noqa: E402
from jsonl import emit  # noqa: E402

jax.config.update("jax_enable_x64", True)


def fabric_rows(folders: list[Path], candidates: list, args) -> list[dict]:
    """Baseline and nested refits of one fabric group; held-out misfits and error ratios of each."""
    ms = [load_measurement(f) for f in folders]
    floor = NoiseFloor.from_captures(ms)
    init = initial_params(ms[0])
    mesh = cusick_mesh(args.spacing, warp_angle_deg=ms[0].warp_angle_deg or 0.0, rim_spacing_m=args.rim)
    base_fit = refine.fit(ms[0], init=init, spacing_m=args.spacing, max_steps=args.max_steps, mesh=mesh)
    base = evaluate_baseline(ms, base_fit, mesh, floor)
    rows = []
    for eff in candidates:
        t0 = time.perf_counter()
        res = nested_refit(ms[0], base_fit, [eff], init=init, mesh=mesh, spacing_m=args.spacing,
                           max_steps=args.max_steps)
        tr = evaluate_baseline(ms, res, mesh, floor)
        rows.append({"effect": eff.name, "theta": np.asarray(res.theta[3:]).tolist(), "status": res.status,
                     "fit_loss": [base_fit.loss, res.loss], "heldout_misfit": [float(np.mean(base.heldout_loss)),
                                                                              float(np.mean(tr.heldout_loss))],
                     "error_ratio": [base.error_ratio, tr.error_ratio], "within_floor": base.within_noise,
                     "n_rows": base.n_rows, "seconds": time.perf_counter() - t0})
    return rows


def make_control(out: Path, fabrics: int, captures: int) -> None:
    """Base-model groups ``bdp_f9N_sample_1_capture_C``: "mid", "heavy", then prior draws (seed 0)."""
    n_drawn = max(fabrics - 2, 0)
    drawn = default_prior().sample(n_drawn, 0)
    members = [example_params("mid"), example_params("heavy")] + [jax.tree.map(lambda a: a[i], drawn)
                                                                  for i in range(n_drawn)]
    for f, params in enumerate(members[:fabrics]):
        for c in range(1, captures + 1):
            make_measurement(out / f"bdp_f{90 + f}_sample_1_capture_{c}", params=params, spacing_m=0.01,
                             rim_spacing_m=0.002, seed=c, warp_angle_deg=None, density_known=False)
            print(f"# control f{90 + f} capture {c}", file=sys.stderr, flush=True)


def summary(rows: list[dict]) -> dict:
    """Per candidate over the fabrics: held-out misfit gains (before − after), how many are
    positive, the sign test and a one-sided paired t test that the mean gain is > 0, and the
    signs of the fitted θ (first component)."""
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
                     "error_ratio_gain": ratio.round(3).tolist(), "theta": th.round(3).tolist(),
                     "theta_positive": int(np.sum(th > 0)), "theta_negative": int(np.sum(th < 0))}
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
    ap.add_argument("--captures", type=int, default=3)
    args = ap.parse_args()
    if args.make_control is not None:
        make_control(args.make_control, args.control_fabrics, args.captures)
        return
    candidates = [REGISTRY[n] for n in args.candidates.split(",") if n]
    only = {f.strip() for f in args.only.split(",") if f.strip()}
    rows = []
    for key, folders in groups(args.data.resolve()).items():
        if only and key not in only or len(folders) < 2:
            continue
        t0 = time.perf_counter()
        for r in fabric_rows(folders, candidates, args):
            r = {"group": key, "captures": len(folders), **r}
            rows.append(r)
            emit(r, args.out)
        print(f"# {key}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    emit({"summary": summary(rows)}, args.out)


if __name__ == "__main__":
    main()
