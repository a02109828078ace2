"""What an off-centre specimen does to the drape, per mesh: drapejax's own drops against Style3D's.

A specimen laid ``--offset-mm`` off the support's centre along +x has a longer overhang on +x and
a shorter one on −x. For each mesh in ``--meshes`` (SPACING_MM or SPACING_MM/RIM_MM: graded from
RIM_MM at the disc edge) the script drops ``--fabric`` with ``effects.OffCentre`` at that offset
and reports the cut edge's shape: a least-squares fit r(φ) = r0 + a1 cos φ + b1 sin φ of its
vertices' horizontal radius (a1: the first harmonic a silhouette shows), and the mean height of
its vertices within 25° of +x and of −x. ``--style3d W`` adds the same figures for the Style3D
captures that ``independent_sim.py --hidden off_centre=... --workdir W`` left there (their cut
edge: the vertices 0.15 m from the specimen's centre in the flat scene).

    python -m experiments.offset_geometry --fabric mid --offset-mm 13 --meshes 20/3,7 --style3d W
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.mesh import CUSICK_RADIUS_M, cusick_mesh  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.virtual_lab import simulate_with_effects  # noqa: E402

if __package__:  # python -m experiments.offset_geometry
    from .common import emit
else:  # python experiments/offset_geometry.py
    from common import emit


def edge_shape(q: np.ndarray) -> dict:
    """r0, a1, b1 (mm) of the cut edge's horizontal radius and its mean height (mm) towards ±x."""
    phi, r = np.arctan2(q[:, 1], q[:, 0]), np.hypot(q[:, 0], q[:, 1])
    coef = np.linalg.lstsq(np.c_[np.ones_like(phi), np.cos(phi), np.sin(phi)], r, rcond=None)[0] * 1e3
    side = np.cos(np.deg2rad(25.0))
    z = lambda near: float(1e3 * q[near, 2].mean())
    return {"r0_mm": float(coef[0]), "a1_mm": float(coef[1]), "b1_mm": float(coef[2]),
            "z_plus_x_mm": z(np.cos(phi) > side), "z_minus_x_mm": z(np.cos(phi) < -side)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabric", default="mid")
    ap.add_argument("--offset-mm", type=float, default=13.0)
    ap.add_argument("--meshes", default="20/3,7", help="comma list of SPACING_MM[/RIM_MM]")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--style3d", type=Path, default=None, help="independent_sim's --workdir with the offset captures")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    shift = np.array([a.offset_mm * 1e-3, 0.0])
    for spec in a.meshes.split(","):
        h, _, rim = spec.partition("/")
        spacing, rim_m = float(h) * 1e-3, (float(rim) * 1e-3 if rim else None)
        t0 = time.perf_counter()
        x, _, status = simulate_with_effects(example_params(a.fabric), {"off_centre": shift}, spacing_m=spacing,
                                             rim_spacing_m=rim_m, seed=a.seed)
        mesh = cusick_mesh(spacing, rim_spacing_m=rim_m)
        edge = np.abs(np.linalg.norm(np.asarray(mesh.rest)[:, :2], axis=1) - CUSICK_RADIUS_M) < 1e-6
        emit({"simulator": "drapejax", "fabric": a.fabric, "offset_mm": a.offset_mm, "mesh": spec,
              "n_verts": int(mesh.n_verts), "status": status, **edge_shape(np.asarray(x)[edge]),
              "seconds": round(time.perf_counter() - t0, 1)}, a.out)
    if a.style3d:
        import trimesh

        from drapejax.bench.newton_peer import hidden_effect_scene

        mesh = cusick_mesh(7e-3)  # independent_sim's default Style3D mesh, the same for every capture
        xy, _, _, _ = hidden_effect_scene(np.asarray(mesh.rest)[:, :2], np.asarray(mesh.faces),
                                          np.asarray(mesh.clamped), {"off_centre": shift}, spacing_m=7e-3)
        edge = np.abs(np.linalg.norm(xy - shift, axis=1) - CUSICK_RADIUS_M) < 1e-6
        for scan in sorted(a.style3d.glob("*/scan.ply")):
            v = np.asarray(trimesh.load(scan, process=False).vertices)
            if len(xy) != len(v):
                raise SystemExit(f"{scan}: {len(v)} vertices, not the 7 mm offset scene's {len(xy)}")
            emit({"simulator": "newton.Style3D", "capture": scan.parent.name, "offset_mm": a.offset_mm, "mesh": "7",
                  **edge_shape(v[edge])}, a.out)

if __name__ == "__main__":
    main()
