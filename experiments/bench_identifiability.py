"""Which measurement tells each fabric effect from k1? The identifiability stage with simulated strip rows.

A clean capture of a library fabric on the fit mesh (20 mm graded from 3 mm at the disc edge),
analysed at the fabric's own rest states (the ideal fit: the fabric that made the capture, over
several drop seeds), with ``drapejax.diagnose.identifiability.analyse_identifiability``: for each
named effect, its std with k1 known and free (prior stds), and the std with k1 free after each
measurement tried in turn: another capture, cantilever strips, pure bending (KES-FB2) tests,
whose rows are simulated at the fabric (``drapejax.diagnose.strip``). Prints one JSON line per
effect, and each effect's strip shifts (apparent log k1 per prior std of θ) per direction.

    python -m experiments.bench_identifiability --fabric mid \
        --effects bending_friction,bending_saturation,bias_asymmetry,heavy_hem
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from drapejax import refine  # noqa: E402
from drapejax.diagnose.identifiability import Identifiability, analyse_identifiability  # noqa: E402
from drapejax.diagnose.strip import BenchResponse  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.material import DIRECTIONS, example_params  # noqa: E402
from drapejax.virtual_lab import simulate_with_effects, write_capture  # noqa: E402

if __package__:  # python -m experiments.bench_identifiability
    from .common import emit
else:  # python experiments/bench_identifiability.py
    from common import emit


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabric", default="mid", help="example fabric (drapejax.material.example_params)")
    ap.add_argument("--effects", default="bending_friction,bending_saturation,bias_asymmetry,heavy_hem")
    ap.add_argument("--seeds", default="1,2,3,4", help="drop seeds of the rest states (the first is the capture)")
    ap.add_argument("--captures", type=int, default=3, help="captures of the specimen at hand")
    ap.add_argument("--results", type=Path, default=None, help="append the JSON lines to this file")
    args = ap.parse_args(argv)
    t0 = time.time()
    p = example_params(args.fabric)
    spacing, rim = refine.FIT_SPACING_M, refine.FIT_RIM_SPACING_M
    seeds = [int(s) for s in args.seeds.split(",")]
    states = [simulate_with_effects(p, {}, spacing_m=spacing, rim_spacing_m=rim, seed=s) for s in seeds]
    truth = {"params": p.to_dict(), "effects": {}, "mesh": {"spacing_m": spacing, "rim_spacing_m": rim}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_capture(Path(tmp) / "c1", states[0][0], states[0][1], truth=truth,
                               areal_density_kg_m2=float(p.density), warp_angle_deg=0.0)
        m = load_measurement(folder)
    effects = [REGISTRY[n] for n in args.effects.split(",")]
    mesh = refine.fit_mesh(m, spacing, rim)
    res = analyse_identifiability(mesh, p, [s[0] for s in states], refine.measured_targets(m), effects,
                                  captures=args.captures)
    bench = BenchResponse(p)
    for e in effects:
        r = res[e.name]
        shifts = {f"{test}_{d}": bench.shift(e, test, d, Identifiability().theta_step)[:, 0].round(4).tolist()
                  for test in BenchResponse.TESTS for d in DIRECTIONS}
        emit({"fabric": args.fabric, "effect": e.name, "captures": args.captures, "states": len(seeds),
              **{k: r[k] for k in ("std_conditional", "std_marginal", "k1_confounding", "identifiable", "separated_by",
                                   "with_measurement")},
              "strip_shift_per_prior_std": shifts, "seconds": round(time.time() - t0, 1)}, args.results)


if __name__ == "__main__":
    main()
