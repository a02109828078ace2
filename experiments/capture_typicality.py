"""Are the virtual-lab captures typical of their generator? Drop-to-drop spread against the misfit's noise.

Effect selection scores models by the selection misfit (``refine.Misfit(profile=True)``): every
row whitened by a fixed drop-to-drop noise (``refine.SIGMA_*``, measured on real scans and on
20–25 mm drops of "mid"). For each virtual-lab case (``common.STRENGTHS``) this makes the
same captures as ``effect_recovery.py`` ("mid", drop seeds 0, 1, …, 25 mm) and drops the hidden
generator itself at ``--seeds`` fresh seeds (2000, 2001, …: ``select.EXPECTED_SEEDS`` onwards).
Per selection row it prints the drops' standard deviation in units of the row's σ (1 when the
noise model is right), each capture's z-score within the drops, the drape coefficients of the
captures and of the drops, and the generator's expected misfit on each capture (½χ² averaged over
its drops; about the number of rows when the captures are typical and the σ right).

Usage: python -m experiments.capture_typicality [--only off_centre,clean] [--seeds 12] [--captures 3]
       [--spacing 0.025] [--out rows.jsonl] [--workdir DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from drapejax import refine
from drapejax.diagnose.select import effect_problem, fresh_drop, selection_misfits
from drapejax.io import load_measurement
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import make_measurement

if __package__:  # python -m experiments.capture_typicality
    from .common import STRENGTHS, emit, generator
else:  # python experiments/capture_typicality.py
    from common import STRENGTHS, emit, generator

jax.config.update("jax_enable_x64", True)

ROWS = ("fold_depth", "dc", "c1_x", "c1_y", "hem", *(f"profile_{round(r * 1000)}mm" for r in refine.PROFILE_RADII_M),
        "height_c1_x", "height_c1_y", "aniso", "shear")
"""Names of the selection rows (``refine.Misfit`` with ``profile``, a warp angle known), in order."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="off_centre,clean", help="comma-separated cases of common.STRENGTHS")
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--spacing", type=float, default=0.025)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--workdir", type=Path, default=None)
    args = ap.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="capture_typicality_"))
    mesh = cusick_mesh(args.spacing, warp_angle_deg=0.0)
    for case in [s.strip() for s in args.only.split(",") if s.strip()]:
        t0 = time.perf_counter()
        effects = STRENGTHS[case]
        folders = [make_measurement(work / case / f"capture_{i}", params=example_params("mid"), effects=effects,
                                    spacing_m=args.spacing, seed=i) for i in range(args.captures)]
        ms = [load_measurement(f) for f in folders]
        misfits = selection_misfits(ms, mesh)
        hidden, theta = generator(effects)
        prob = effect_problem(refine.measured_targets(ms[0]), hidden, example_params("mid"), mesh, args.spacing)
        xs = [x for s in range(2000, 2000 + args.seeds) if (x := fresh_drop(prob, theta, s)) is not None]
        f_drops = [misfits[0].hard(x) for x in xs]
        f_caps = [misfits[0].hard(np.asarray(m.scan_vertices)) for m in ms]
        # whitened rows of every drop against capture 0: r = (feature - capture 0) / σ, so drop
        # spread and capture offsets are both in σ units
        r = np.array([misfits[0].whiten(f) for f in f_drops])
        caps = np.array([misfits[0].whiten(f) for f in f_caps])
        sd = r.std(axis=0, ddof=1)
        z = (caps - r.mean(axis=0)) / sd
        per_capture = [float(np.mean([mf.loss(x) for x in xs])) for mf in misfits]
        emit({"case": case, "hidden_values": effects, "drops": len(xs), "rows": list(ROWS[:r.shape[1]]),
              "drop_sd_in_sigma": sd.tolist(), "capture_z": z.tolist(),
              "dc_captures": [float(f[0]) for f in f_caps], "dc_drops": [float(f[0]) for f in f_drops],
              "expected_misfit_per_capture": per_capture, "n_rows": int(r.shape[1]),
              "seconds": time.perf_counter() - t0}, args.out)


if __name__ == "__main__":
    main()
