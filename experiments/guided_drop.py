"""Can a drop be steered into a measured fold pattern? (a study for refinement, issue 5)

The fits compare phase-invariant observables because every drop lands on its own fold pattern,
and that fold noise bounds how well one capture pins k1 (``refine_synthetic.py``). If the
simulated drape could be put on the measured fold pattern, phase-dependent residuals (the rim
profile itself) would become usable. This study tries the simplest steering: a temporary energy
that keeps every skirt vertex inside the measured outline r(φ) and holds the hem on it,

    E = ½ k Σ_i A_i d_i²,  d_i = ρ_i − r(φ_i) on the hem,  max(ρ_i − r(φ_i), 0) elsewhere,

applied in a second drop that starts from an ordinary drop's rest state, then removed for a
final static solve (the "released" state). The measured drape is "mid" dropped with seed 0 on
the default fit mesh; each run drops with another seed at k1 scaled by ``--scales``. Printed
per run, for the unguided, the guided (guide still on) and the released state: DC minus the measured DC, fold count, and
the rms difference of the rim profiles (mm). Success would be a released state on the
measured fold pattern: rim rms near zero at scale 1.

    python -m experiments.guided_drop                  # about 5 minutes
    python -m experiments.guided_drop --seeds 1,2 --scales 1 --stiffness 1e3
"""

from __future__ import annotations

import argparse
import json
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe, refine  # noqa: E402
from drapejax.energy import AbstractEnergy, default_energies, safe_norm  # noqa: E402
from drapejax.material import FabricParams, example_params  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import drape, quick_config, static_solve  # noqa: E402


class OutlineGuide(AbstractEnergy):
    """Keeps skirt vertices inside the outline ``profile`` (r at φ_j = 2πj/n) and the hem on it."""

    profile: jnp.ndarray
    stiffness_n_per_m3: float = eqx.field(static=True, default=1e4)

    def elements(self, mesh):
        hem = jnp.linalg.norm(mesh.rest[:, :2], axis=1) > mesh.info.specimen_radius_m - 1e-3
        return jnp.arange(mesh.n_verts)[:, None], (mesh.vertex_area * ~mesh.clamped, hem)

    def element_energy(self, xe, data, params):
        w, hem = data
        p = jnp.where(w > 0, xe[0], jnp.array([0.12, 0.0, 0.0]))  # clamped vertices sit at the origin
        n = self.profile.shape[0]
        t = jnp.mod(jnp.arctan2(p[1], p[0]), 2 * jnp.pi) / (2 * jnp.pi) * n
        i0 = jnp.floor(t).astype(jnp.int32) % n
        f = t - jnp.floor(t)
        r = (1 - f) * self.profile[i0] + f * self.profile[(i0 + 1) % n]
        rho = safe_norm(p[:2])
        d = jnp.where(hem, rho - r, jnp.maximum(rho - r, 0.0))
        return 0.5 * self.stiffness_n_per_m3 * w * d * d


def _floats(s: str) -> list[float]:
    return [float(v) for v in s.split(",") if v]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3,4,5,6")
    ap.add_argument("--scales", type=_floats, default=[1.0, 1.3], help="k1 (and k2) multipliers of the runs")
    ap.add_argument("--stiffness", type=float, default=1e4, help="guide stiffness, N/m³")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    mesh = cusick_mesh(refine.FIT_SPACING_M, rim_spacing_m=refine.FIT_RIM_SPACING_M)
    faces = np.asarray(mesh.faces)
    base = default_energies("cusick")
    cfg = quick_config(exact_step_hessian=False, exact_static_hessian=False)
    plain = jax.jit(lambda p, s: drape(mesh, p, s, terms=base, config=cfg))
    guided = eqx.filter_jit(lambda p, s, guide, x0: drape(mesh, p, s, terms=base + (guide,), config=cfg, x0=x0))
    release = jax.jit(lambda p, x: static_solve(mesh, p, x, terms=base, config=cfg).x)

    def observe_(x):
        sil = observe.silhouette(np.asarray(x), faces, n=256, extent_m=refine.EXTENT_M)
        prof = observe.rim_profile(sil, refine.EXTENT_M)
        return observe.drape_coefficient(sil, refine.EXTENT_M), prof, observe.fold_count(prof)

    mid = example_params("mid")
    dc_m, prof_m, folds_m = observe_(plain(mid, 0).x)
    print(json.dumps({"measured": {"seed": 0, "dc": dc_m, "folds": folds_m}}), flush=True)
    guide = OutlineGuide(jnp.asarray(prof_m), args.stiffness)
    for scale in args.scales:
        kw = mid.to_dict()
        for k in kw:
            if k.startswith("bend_k"):
                kw[k] *= scale
        p = FabricParams.from_dict(kw)
        for seed in (int(s) for s in args.seeds.split(",")):
            xu = plain(p, seed).x
            xg = guided(p, seed, guide, xu).x
            xr = release(p, xg)
            row = {"scale": scale, "seed": seed}
            for name, x in (("unguided", xu), ("guided", xg), ("released", xr)):
                dc, prof, folds = observe_(x)
                row[name] = {"ddc": dc - dc_m, "folds": folds,
                             "rim_rms_mm": 1e3 * float(np.sqrt(np.mean((prof - prof_m) ** 2)))}
            print(json.dumps(row), flush=True)
    print(json.dumps({"seconds": time.perf_counter() - t0}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
