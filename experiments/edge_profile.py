"""The skirt's height just past the disc edge: real scans against their baseline fits.

For each named fabric, the first capture is fitted as ``drapejax estimate`` fits it (network
estimate, then ``refine.fit`` on the default fit mesh), and the median height of the fitted rest
shape and of the scan is printed in rings of radius beyond the support disc (r = 90 mm). It
shows where the scans hang lower than the fits (the shared deficit of ``pooled_real.py``).
With ``--effect NAME`` the fit is also refitted with that effect (``select.nested_refit``, θ free
from null, as ``pooled_real.py`` refits; or held at ``--theta``, only k1 free) and the refit's
rings are printed too: does the effect put the kink where the scans have it? With ``--redrop
SPACING_MM RIM_MM`` the baseline fit's parameters are also dropped afresh on that mesh
(``virtual_lab.simulate_with_effects``, no effect, seeds 0 and 1): is a missing kink the fit
mesh's, or the model's?
Usage: python -m experiments.edge_profile [f01 f14 ...] [--effect clamp_hinge [--theta 0.3]]
       [--redrop 10 1] [--rings 85,87.5,90,...] [--out edge.jsonl]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from drapejax import refine
from drapejax.diagnose import initial_params
from drapejax.diagnose.select import held_refit, nested_refit
from drapejax.effects import REGISTRY
from drapejax.io import load_measurement
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import simulate_with_effects

if __package__:  # python -m experiments.edge_profile
    from .common import emit, groups
else:  # python experiments/edge_profile.py
    from common import emit, groups

jax.config.update("jax_enable_x64", True)

EDGES_MM = (85.0, 87.5, 90.0, 92.5, 95.0, 100.0, 110.0, 120.0)
"""Ring boundaries (radius, mm); the support disc's edge is at 90 mm."""


def ring_heights_mm(verts: np.ndarray, edges_mm=EDGES_MM) -> list[float | None]:
    """Median z (mm) of the vertices in each ring of ``edges_mm`` (None where a ring is empty)."""
    r = 1e3 * np.hypot(verts[:, 0], verts[:, 1])
    out = []
    for a, b in zip(edges_mm[:-1], edges_mm[1:]):
        z = verts[(r >= a) & (r < b), 2]
        out.append(float(1e3 * np.median(z)) if z.size else None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fabrics", nargs="*", default=["f01", "f14"])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / "../shared/data/real_cusick")
    ap.add_argument("--effect", default=None, help="also refit with this effect (a REGISTRY name)")
    ap.add_argument("--theta", type=float, nargs="+", default=None, help="hold the effect at this θ (else free)")
    ap.add_argument("--max-steps", type=int, default=6, help="refit steps (as pooled_real.py)")
    ap.add_argument("--redrop", type=float, nargs=2, default=None, metavar=("SPACING_MM", "RIM_MM"),
                    help="also drop the baseline fit's parameters on this mesh (seeds 0 and 1)")
    ap.add_argument("--rings", default=",".join(f"{e:g}" for e in EDGES_MM), help="ring boundaries, mm")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    edges = tuple(float(e) for e in args.rings.split(","))
    rings = lambda v: ring_heights_mm(np.asarray(v, float), edges)
    folders = groups(args.data.resolve())
    for fab in args.fabrics:
        m = load_measurement(folders[fab][0])
        mesh = cusick_mesh(refine.FIT_SPACING_M, warp_angle_deg=m.warp_angle_deg or 0.0,
                           rim_spacing_m=refine.FIT_RIM_SPACING_M)
        init = initial_params(m)
        res = refine.fit(m, init=init, spacing_m=refine.FIT_SPACING_M, mesh=mesh)
        row = {"fabric": fab, "capture": folders[fab][0].name, "rings_mm": list(zip(edges[:-1], edges[1:])),
               "scan_z_mm": rings(m.scan_vertices), "fit_z_mm": rings(res.x), "fit_status": res.status}
        if args.effect is not None:
            kw = dict(init=init, mesh=mesh, spacing_m=refine.FIT_SPACING_M, max_steps=args.max_steps,
                      config=refine.CONTINUATION_CONFIG)
            eff = REGISTRY[args.effect]
            ref = (nested_refit(m, res, [eff], **kw) if args.theta is None
                   else held_refit(m, res, [eff], np.asarray(args.theta, float), **kw))
            row.update({"effect": args.effect, "theta": np.asarray(ref.theta[3:]).tolist(),
                        "k1_log_scale": [np.asarray(res.theta[:3]).tolist(), np.asarray(ref.theta[:3]).tolist()],
                        "fit_loss": [res.loss, ref.loss], "refit_z_mm": rings(ref.x),
                        "refit_status": ref.status})
        if args.redrop is not None:
            drops = [simulate_with_effects(res.params, {}, spacing_m=1e-3 * args.redrop[0],
                                           rim_spacing_m=1e-3 * args.redrop[1], seed=seed) for seed in (0, 1)]
            row.update({"redrop_mesh_mm": args.redrop, "redrop_verts": len(drops[0][0]),
                        "redrop_z_mm": [rings(x) for x, _, _ in drops], "redrop_status": [st for _, _, st in drops]})
        emit(row, args.out)


if __name__ == "__main__":
    main()
