"""Peer benchmark: the Cusick drape run in Newton's ``SolverStyle3D`` (NVIDIA warp, on CPU).

The command line of ``drapejax.bench.newton_peer.newton_time_to_rest`` (its module docstring
gives the scene and the material mapping): the mid example fabric on a ``cusick_mesh`` of the
given spacing. Run ``python benchmarks/newton_peer.py --spacing-mm 5 --json``; see
benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys

import numpy as np

from drapejax.bench.newton_peer import newton_time_to_rest
from drapejax.bench.newton_peer import style3d_material  # noqa: F401  (tests/test_export.py imports it from here)
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh


def main(argv: list[str] | None = None) -> int:
    """CLI: the mid example fabric on a ``cusick_mesh`` of the given spacing."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing-mm", type=float, default=5.0, help="mesh edge length, mm")
    ap.add_argument("--fabric", default="mid", help="drapejax example fabric: light, mid or heavy")
    ap.add_argument("--dt", type=float, default=1.0 / 600.0, help="time step, s")
    ap.add_argument("--max-time", type=float, default=30.0, help="simulated-time cap, s")
    ap.add_argument("--iterations", type=int, default=4, help="Style3D nonlinear iterations per step")
    ap.add_argument("--linear-iterations", type=int, default=10, help="Style3D PCG iterations per nonlinear iteration")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs (median reported)")
    ap.add_argument("--self-collision", action="store_true", help="enable Style3D cloth self-collision")
    ap.add_argument("--raw-bending", action="store_true", help="pass k1 through uncalibrated")
    ap.add_argument("--json", action="store_true", help="print the result as one JSON object")
    args = ap.parse_args(argv)
    mesh = cusick_mesh(args.spacing_mm * 1e-3)
    with contextlib.redirect_stdout(sys.stderr):  # warp and newton log compile times to stdout
        result = newton_time_to_rest(
            np.asarray(mesh.rest)[:, :2], np.asarray(mesh.faces), np.asarray(mesh.clamped),
            example_params(args.fabric).to_dict(), dt=args.dt, max_time_s=args.max_time,
            iterations=args.iterations, linear_iterations=args.linear_iterations,
            self_collision=args.self_collision, calibrate_bending=not args.raw_bending, repeats=args.repeats)
    result["spacing_mm"] = args.spacing_mm
    result["fabric"] = args.fabric
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:>24}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
