"""What an off-centre specimen does to the drape, per mesh: drapejax's own drops against Style3D's.

A specimen laid ``--offset-mm`` off the support's centre along +x has a longer overhang on +x and
a shorter one on −x. For each mesh in ``--meshes`` (SPACING_MM or SPACING_MM/RIM_MM: graded from
RIM_MM at the disc edge) the script drops ``--fabric`` with ``effects.OffCentre`` at that offset
and reports the cut edge's shape: a least-squares fit r(φ) = r0 + a1 cos φ + b1 sin φ of its
vertices' horizontal radius (a1: the first harmonic a silhouette shows), the mean height of its
vertices within 25° of +x and of −x, and the world-frame first harmonic of the skirt's height
(``refine.height_first_harmonic``; with ``--offset-mm 0`` and several ``--seeds``, its
drop-to-drop noise). ``--style3d W`` adds the same figures for the Style3D
captures that ``independent_sim.py --hidden off_centre=... --workdir W`` left there (their cut
edge: the vertices 0.15 m from the specimen's centre in the flat scene). With ``--style3d W`` each
drapejax drop is also scored against those captures on the rows effect selection scores drops by
(``refine.Misfit(profile=True)``, ½χ² averaged over the captures), with and without the height's
world-frame first harmonic (``refine.height_first_harmonic``), at the captures' true fabric
(``truth.json``) with its k1 times ``--k-factor``; ``--offset-mm 0`` gives the model without the
offset.

    python -m experiments.offset_geometry --fabric mid --offset-mm 13 --meshes 20/3,7 --style3d W
    python -m experiments.offset_geometry --offset-mm 0,13 --meshes 20/3 --seeds 100,101,102 --style3d W
    python -m experiments.offset_geometry --fabric light --offset-mm 0 --meshes 20/3 --seeds 1,2,3
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe, refine  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.mesh import CUSICK_RADIUS_M, cusick_mesh  # noqa: E402
from drapejax.material import FabricParams, example_params  # noqa: E402
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
    ap.add_argument("--offset-mm", default="13", help="comma list of offsets along +x, mm")
    ap.add_argument("--meshes", default="20/3,7", help="comma list of SPACING_MM[/RIM_MM]")
    ap.add_argument("--seeds", default="1", help="comma list of drop seeds")
    ap.add_argument("--k-factor", type=float, default=1.0, help="k1 factor on the captures' fabric (--style3d)")
    ap.add_argument("--style3d", type=Path, default=None, help="independent_sim's --workdir with the offset captures")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    offsets = [float(v) for v in a.offset_mm.split(",")]
    captures = sorted(p.parent for p in a.style3d.glob("*/truth.json")) if a.style3d else []
    params = example_params(a.fabric)
    if captures:
        truth = json.loads((captures[0] / "truth.json").read_text())["params"]
        params = FabricParams.from_dict({k: v * a.k_factor if k.startswith("bend_k") else v for k, v in truth.items()})
    targets = [refine.measured_targets(load_measurement(c)) for c in captures]
    for spec in a.meshes.split(","):
        h, _, rim = spec.partition("/")
        spacing, rim_m = float(h) * 1e-3, (float(rim) * 1e-3 if rim else None)
        mesh = cusick_mesh(spacing, rim_spacing_m=rim_m)
        edge = np.abs(np.linalg.norm(np.asarray(mesh.rest)[:, :2], axis=1) - CUSICK_RADIUS_M) < 1e-6
        misfits = [(refine.Misfit(mesh, t, profile=True),
                    refine.Misfit(mesh, dataclasses.replace(t, height_c1_m=None), profile=True)) for t in targets]
        for offset in offsets:
            for seed in [int(v) for v in a.seeds.split(",")]:
                t0 = time.perf_counter()
                effects = {"off_centre": np.array([offset * 1e-3, 0.0])} if offset else {}
                x, _, status = simulate_with_effects(params, effects, spacing_m=spacing, rim_spacing_m=rim_m, seed=seed)
                x = np.asarray(x)
                row = {"simulator": "drapejax", "fabric": a.fabric, "offset_mm": offset, "mesh": spec, "seed": seed,
                       "n_verts": int(mesh.n_verts), "status": status, **edge_shape(x[edge])}
                hm = observe.height_map(x, np.asarray(mesh.faces), n=256, extent_m=refine.EXTENT_M)
                row["height_c1_mm"] = (1e3 * refine.height_first_harmonic(hm, refine.EXTENT_M)).tolist()
                if misfits:
                    row.update(k_factor=a.k_factor, loss=float(np.mean([m.loss(x) for m, _ in misfits])),
                               loss_without_height_c1=float(np.mean([m.loss(x) for _, m in misfits])))
                emit({**row, "seconds": round(time.perf_counter() - t0, 1)}, a.out)
    if captures:
        import trimesh

        from drapejax.bench.newton_peer import hidden_effect_scene

        mesh = cusick_mesh(7e-3)  # independent_sim's default Style3D mesh, the same for every capture
        scenes = {}  # the offset scene and its cut-edge mask, built once per offset
    for c, t in zip(captures, targets):
        effects = json.loads((c / "truth.json").read_text()).get("effects", {})
        if "off_centre" not in effects:
            raise SystemExit(f"{c / 'truth.json'}: no 'off_centre' among the hidden effects; --style3d needs the "
                             f"captures of independent_sim.py --hidden off_centre=DX,DY")
        shift = np.asarray(effects["off_centre"]["theta"], float)
        if tuple(shift) not in scenes:
            xy, _, _, _ = hidden_effect_scene(np.asarray(mesh.rest)[:, :2], np.asarray(mesh.faces),
                                              np.asarray(mesh.clamped), {"off_centre": shift}, spacing_m=7e-3)
            scenes[tuple(shift)] = (len(xy), np.abs(np.linalg.norm(xy - shift, axis=1) - CUSICK_RADIUS_M) < 1e-6)
        n, edge = scenes[tuple(shift)]
        v = np.asarray(trimesh.load(c / "scan.ply", process=False).vertices)
        if n != len(v):
            raise SystemExit(f"{c / 'scan.ply'}: {len(v)} vertices, not the 7 mm offset scene's {n}")
        emit({"simulator": "newton.Style3D", "capture": c.name, "offset_mm": float(shift[0]) * 1e3, "mesh": "7",
              **edge_shape(v[edge]), "height_c1_mm": (1e3 * t.height_c1_m).tolist()}, a.out)

if __name__ == "__main__":
    main()
