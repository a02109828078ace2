"""Peer benchmark: the Cusick drape run in Newton's ``SolverStyle3D`` (NVIDIA warp, on CPU).

The specimen starts flat at z = 0 on a support cylinder (top at z = 0, radius of the clamped
region, 0.2 m tall, standing on a ground plane); the clamped vertices are fixed and the rest
falls under gravity along -z until the largest particle speed drops below ``rest_speed``.

Material mapping from the drapejax schema (SI) to Style3D:

* areal density (kg/m²) -> ``density`` (lumped to the vertices by Newton).
* stretch: Style3D's membrane energy per area is
  ``ku/2 (|F_u|-1)² + kv/2 (|F_v|-1)² + ks/2 (F_u·F_v)²`` with panel axes u = x, v = y
  (u is the warp), so ``tri_aniso_ke = (alpha_warp, alpha_weft, alpha_bias / 2)`` N/m: a
  uniaxial tension per width ``alpha ε`` along warp/weft and the drapejax shear modulus
  ``alpha_bias / 2``. ``stretch_beta_*`` (stiffening) has no Style3D counterpart.
* bending: Style3D uses Bergou's quadratic hinge energy with a per-edge stiffness
  ``k_e = K0 sin¹²θ + K1 cos¹²θ + 4 K2 sin²θ cos²θ`` (θ: hinge direction from the warp),
  so K0 acts on warp curvature, K1 on weft curvature and K2 mostly on bias. The discrete
  energy of a cylindrical bend is about 3.4 times ``k_e κ²/2`` per area, so by default
  (K0, K1, K2) are solved, on the given mesh, such that uniform cylindrical bends along
  warp, weft and 45° bias have exactly the drapejax strip rigidities ``bend_k1_*`` (N·m).
  ``calibrate_bending=False`` instead passes the rigidities through
  (``K = (k1_warp, k1_weft, k1_bias - (k1_warp + k1_weft)/64)``), a ~3.4x stiffer fabric.
  ``bend_k2_*`` (softening) has no Style3D counterpart.

``newton`` and ``warp`` are imported only inside ``newton_time_to_rest`` (every field None when
they are not installed) and ``newton_rest_state`` (ImportError). Run
``python benchmarks/newton_peer.py --spacing-mm 5 --json``; see benchmarks/README.md.
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from jaxtyping import Bool, Float, Int

from ..effects.heavy_hem import HEM_BAND_M
from ..material import BENDING_KEYS, STRETCH_KEYS, FabricParams, G
from ..mesh import CUSICK_RADIUS_M, _delaunay

SUPPORT_HEIGHT_M = 0.2
"""Height of the support cylinder; the ground plane lies at its foot, z = -0.2 m."""

PARTICLE_RADIUS_M = 1e-3
"""Contact radius of the cloth particles against the support and the ground."""

COLLIDE_EVERY = 10
"""Steps between body-contact updates (Newton's Style3D example: once per 10 substeps)."""

RESULT_KEYS = (
    "rest_s", "rest_s_runs", "setup_s", "sim_time_s", "steps", "final_max_speed", "converged",
    "drape_coefficient", "min_z_m", "max_depth_in_support_m", "dt", "iterations",
    "linear_iterations", "self_collision", "calibrate_bending", "tri_aniso_ke", "edge_aniso_ke",
    "ignored_params", "n_verts", "n_faces", "device", "load_avg_1min", "newton_version", "warp_version",
)


@dataclass(frozen=True)
class Style3DMaterial:
    """Style3D material coefficients in Newton's units.

    Attributes:
        density: areal density, kg/m².
        tri_aniso_ke: (warp, weft, shear) membrane stiffness, N/m.
        edge_aniso_ke: (K0, K1, K2) hinge stiffness coefficients, N·m (see module docstring).
    """

    density: float
    tri_aniso_ke: tuple[float, float, float]
    edge_aniso_ke: tuple[float, float, float]


def hinge_basis(theta: Float[np.ndarray, " e"]) -> Float[np.ndarray, "e 3"]:
    """Style3D's directional weights (sin¹²θ, cos¹²θ, 4 sin²θ cos²θ) of hinges at angle θ (rad)."""
    s2, c2 = np.sin(theta) ** 2, np.cos(theta) ** 2
    return np.stack([s2**6, c2**6, 4.0 * s2 * c2], -1)


def _interior_hinges(model) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edge stencils (o0, o1, v0, v1), rest areas A0+A1 (m²), cotangents and interior mask."""
    edges = model.edge_indices.numpy()
    return (edges, model.style3d.edge_rest_area.numpy().astype(float),
            model.style3d.edge_bending_cot.numpy().astype(float), (edges[:, 0] >= 0) & (edges[:, 1] >= 0))


def bending_calibration(model, xy: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, "3 3"]:
    """Strip rigidity (N·m) along warp, weft and 45° bias per unit (K0, K1, K2) on this mesh.

    Row d, column j is the continuum rigidity ``2E/(κ² A)`` that Newton's discrete hinge energy
    gives for the height field ``z = κ s²/2`` (s the coordinate along direction d) when only
    ``K_j = 1``. Cotangent weights reproduce linear fields, so only z contributes. The area A
    is the share ``(A0+A1)/3`` of the interior hinges, so the open hem does not enter.
    """
    edges, area, cot, inner = _interior_hinges(model)
    edges, area, cot = edges[inner], area[inner], cot[inner]
    w = np.stack([-cot[:, 0] - cot[:, 2], -cot[:, 1] - cot[:, 3], cot[:, 2] + cot[:, 3], cot[:, 0] + cot[:, 1]], 1)
    hinge = xy[edges[:, 3]] - xy[edges[:, 2]]
    basis = hinge_basis(np.arctan2(hinge[:, 1], hinge[:, 0]))
    rows = []
    for angle in (0.0, 0.5 * np.pi, 0.25 * np.pi):
        s = xy @ np.array([np.cos(angle), np.sin(angle)])
        lap = np.einsum("ej,ej->e", w, 0.5 * s[edges] ** 2)
        energy_per_k = 0.5 * (3.0 / area) * lap**2
        rows.append(2.0 * energy_per_k @ basis / (area.sum() / 3.0))
    return np.array(rows)


def style3d_material(params: FabricParams, calibration: Float[np.ndarray, "3 3"] | None) -> Style3DMaterial:
    """Map drapejax parameters to Style3D coefficients (see the module docstring).

    Args:
        params: one fabric.
        calibration: ``bending_calibration`` of the mesh, or None to pass k1 through.
    """
    k1 = np.array([float(params.bend_k1_warp), float(params.bend_k1_weft), float(params.bend_k1_bias)])
    if calibration is None:
        edge = (k1[0], k1[1], k1[2] - (k1[0] + k1[1]) / 64.0)
    else:
        edge = tuple(np.linalg.solve(calibration, k1))
        if min(edge) < 0.0:
            raise ValueError(f"bend_k1_* = {k1.tolist()} N*m need a negative Style3D hinge coefficient "
                             f"{list(edge)}; Style3D's directional law cannot represent this fabric")
    tri = (float(params.stretch_alpha_warp), float(params.stretch_alpha_weft), 0.5 * float(params.stretch_alpha_bias))
    return Style3DMaterial(float(params.density), tri, tuple(float(e) for e in edge))


def drape_coefficient(q: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], disk_radius_m: float,
                      flat_area_m2: float, pixel_m: float = 1e-4) -> float:
    """DC = (projected area - disc area) / (flat specimen area - disc area), rasterised in xy."""
    half = float(np.abs(q[:, :2]).max()) + 2 * pixel_m
    n = int(np.ceil(2 * half / pixel_m))
    img = np.zeros((n, n), np.uint8)
    pts = np.round((q[:, :2] + half) / pixel_m * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillPoly(img, list(pts[faces]), 1, lineType=cv2.LINE_8, shift=4)
    disc = np.pi * disk_radius_m**2
    return float((img.sum() * pixel_m**2 - disc) / (flat_area_m2 - disc))


def _flat_area(xy: Float[np.ndarray, "n 2"], faces: Int[np.ndarray, "m 3"]) -> float:
    e1, e2 = xy[faces[:, 1]] - xy[faces[:, 0]], xy[faces[:, 2]] - xy[faces[:, 0]]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())


def _build(newton, wp, xy, faces, clamped, params, calibrate_bending, iterations, linear_iterations,
           self_collision, z0=None, mass_scale=None):
    """Model, solver and collision pipeline of the drape scene, plus the material used.

    ``z0``: initial heights of the vertices, m (None: flat at z = 0); ``mass_scale``: a factor on
    each vertex's lumped mass (None: the fabric's density everywhere)."""
    builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=(0.0, 0.0, -G))
    newton.solvers.SolverStyle3D.register_custom_attributes(builder)
    nominal = style3d_material(params, None)
    newton.solvers.style3d.add_cloth_mesh(
        builder, pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=np.c_[xy, np.zeros(len(xy)) if z0 is None else z0].tolist(), indices=faces.ravel().tolist(),
        density=nominal.density, tri_aniso_ke=wp.vec3(*nominal.tri_aniso_ke),
        edge_aniso_ke=wp.vec3(1.0, 1.0, 1.0), particle_radius=PARTICLE_RADIUS_M)
    if mass_scale is not None:
        for i in np.flatnonzero(np.asarray(mass_scale) != 1.0):
            builder.particle_mass[i] *= float(mass_scale[i])
    for i in np.flatnonzero(clamped):
        builder.particle_mass[i] = 0.0
        builder.particle_flags[i] &= ~newton.ParticleFlags.ACTIVE
    support_r = float(np.linalg.norm(xy[clamped], axis=1).max())
    builder.add_shape_cylinder(-1, xform=wp.transform(wp.vec3(0.0, 0.0, -0.5 * SUPPORT_HEIGHT_M), wp.quat_identity()),
                               radius=support_r, half_height=0.5 * SUPPORT_HEIGHT_M)
    builder.add_ground_plane(height=-SUPPORT_HEIGHT_M)
    model = builder.finalize(device="cpu")

    edges, _, _, inner = _interior_hinges(model)  # boundary hinges carry no bending energy
    hinge = xy[edges[:, 3]] - xy[edges[:, 2]]
    basis = hinge_basis(np.arctan2(hinge[:, 1], hinge[:, 0]))
    props = model.edge_bending_properties.numpy()
    if not np.allclose(props[inner, 0], basis[inner].sum(1), rtol=1e-4, atol=1e-6):
        raise RuntimeError("newton's Style3D hinge-stiffness law differs from hinge_basis(); "
                           "the bending mapping in drapejax/bench/newton_peer.py needs updating")
    material = style3d_material(params, bending_calibration(model, xy) if calibrate_bending else None)
    props[:, 0] = basis @ np.array(material.edge_aniso_ke)
    model.edge_bending_properties.assign(props)

    config = newton.solvers.SolverStyle3D.Config(iterations=iterations, linear_iterations=linear_iterations)
    solver = newton.solvers.SolverStyle3D(model, config=config)
    if not self_collision:
        solver.collision.stiff_vf = solver.collision.stiff_ee = solver.collision.stiff_ef = 0.0
    pipeline = newton.CollisionPipeline(model)
    return model, solver, pipeline, material


def _drop(model, solver, pipeline, dt: float, rest_speed: float, max_steps: int):
    """Step from flat until the max particle speed falls below ``rest_speed`` (after moving)."""
    contacts = pipeline.contacts()
    s0, s1, control = model.state(), model.state(), model.control()
    moving, vmax, step = False, 0.0, 0
    start = time.perf_counter()
    for step in range(1, max_steps + 1):
        if step % COLLIDE_EVERY == 1:
            pipeline.collide(s0, contacts)
        s0.clear_forces()
        solver.step(s0, s1, control, contacts, dt)
        s0, s1 = s1, s0
        qd = s0.particle_qd.numpy()
        vmax = float(np.sqrt(np.einsum("ij,ij->i", qd, qd).max()))
        moving |= vmax > rest_speed
        if moving and vmax < rest_speed:
            break
    wall = time.perf_counter() - start
    return wall, step, vmax, moving and vmax < rest_speed, s0.particle_q.numpy().astype(float)


def _unavailable(reason: str) -> dict[str, Any]:
    return {**dict.fromkeys(RESULT_KEYS), "device": "cpu", "reason": reason}


def _scene_arrays(verts_xy, faces, clamped, caller: str):
    """The mesh arrays as float / int64 / bool, or one clear error naming ``caller``."""
    xy, faces, clamped = np.asarray(verts_xy, float), np.asarray(faces, np.int64), np.asarray(clamped, bool)
    if xy.ndim != 2 or xy.shape[1] != 2 or faces.ndim != 2 or faces.shape[1] != 3 or clamped.shape != (len(xy),):
        raise ValueError(f"{caller}: expected verts_xy (n, 2), faces (m, 3), clamped (n,); got "
                         f"{xy.shape}, {faces.shape}, {clamped.shape}")
    if not clamped.any():
        raise ValueError(f"{caller}: no clamped vertices; the specimen would fall off the support")
    return xy, faces, clamped


SCENE_EFFECTS = ("off_centre", "heavy_hem")
"""Effects of ``drapejax.effects`` that ``hidden_effect_scene`` makes in the Style3D scene."""


def hidden_effect_scene(
    verts_xy: Float[np.ndarray, "n 2"],
    faces: Int[np.ndarray, "m 3"],
    clamped: Bool[np.ndarray, " n"],
    effects: dict,
    *,
    spacing_m: float,
    specimen_radius_m: float = CUSICK_RADIUS_M,
    hem_band_m: float = HEM_BAND_M,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A Cusick scene with setup effects made the way the other simulator would meet them, not
    through drapejax's effect energies: ``effects`` {name: θ} as in ``drapejax.effects``.

    * ``off_centre`` θ = (dx, dy) m: the specimen's material lies at X + s in the world and the
      support edge stays a circle at the origin. The scene is meshed anew: the specimen's vertices
      shifted by s, those within half a spacing of the support edge replaced by a ring on it
      (spacing ``spacing_m``), Delaunay triangles of the whole, and every vertex on or inside the
      edge clamped.
    * ``heavy_hem`` θ = (r,): every vertex within ``hem_band_m`` of the cut edge carries 1 + r
      times its lumped mass (``HeavyHem``'s band of extra areal mass r·ρ).

    The mesh arrays are those of a centred specimen (``drapejax.mesh.cusick_mesh``), warp along +x.
    Returns (verts_xy, faces, clamped, mass_scale) of the scene; another effect raises ValueError
    naming it.
    """
    xy, faces, clamped = _scene_arrays(verts_xy, faces, clamped, "hidden_effect_scene")
    unknown = sorted(set(effects) - set(SCENE_EFFECTS))
    if unknown:
        raise ValueError(f"hidden_effect_scene: cannot make {unknown} in the Style3D scene; it makes {SCENE_EFFECTS}")
    disk_r = float(np.linalg.norm(xy[clamped], axis=1).max())
    rim = np.linalg.norm(xy, axis=1) > specimen_radius_m - hem_band_m
    if "off_centre" in effects:
        shift = np.asarray(effects["off_centre"], float).reshape(2)
        if np.linalg.norm(shift) > specimen_radius_m - disk_r - spacing_m:
            raise ValueError(f"hidden_effect_scene: off_centre {shift.tolist()} m moves the cut edge onto the support")
        world = xy + shift
        keep = np.abs(np.linalg.norm(world, axis=1) - disk_r) > 0.5 * spacing_m
        n_ring = int(np.ceil(2 * np.pi * disk_r / spacing_m))
        phi = 2 * np.pi * np.arange(n_ring) / n_ring
        xy = np.concatenate([world[keep], disk_r * np.c_[np.cos(phi), np.sin(phi)]])
        rim = np.concatenate([rim[keep], np.zeros(n_ring, bool)])
        faces = np.asarray(_delaunay(xy), np.int64)
        clamped = np.linalg.norm(xy, axis=1) <= disk_r * (1 + 1e-9)
    mass_scale = np.ones(len(xy))
    if "heavy_hem" in effects:
        mass_scale[rim] = 1.0 + float(np.ravel(effects["heavy_hem"])[0])
    return xy, faces, clamped, mass_scale


def newton_rest_state(
    verts_xy: Float[np.ndarray, "n 2"],
    faces: Int[np.ndarray, "m 3"],
    clamped: Bool[np.ndarray, " n"],
    params: dict,
    *,
    seed: int | None = None,
    jitter_m: float = 1e-4,
    dt: float = 1.0 / 600.0,
    rest_speed: float = 1e-3,
    max_time_s: float = 30.0,
    iterations: int = 4,
    linear_iterations: int = 10,
    calibrate_bending: bool = True,
    mass_scale: Float[np.ndarray, " n"] | None = None,
) -> tuple[Float[np.ndarray, "n 3"], dict[str, Any]]:
    """Rest positions (m) of the Cusick drape in Newton's SolverStyle3D, for use as data from an
    independent simulator (``experiments/independent_sim.py``); raises ImportError without newton.

    ``seed``: None drops from flat (the fold pattern is set by the mesh alone); an integer lifts
    the free vertices by seeded heights, uniform in [0, ``jitter_m``), so that captures of one
    fabric are separate drops (three of "mid" at 7 mm still came out alike: DC 0.523-0.532, 8
    folds each; real repeated drops differ more). ``mass_scale``: a factor on each vertex's mass
    (a heavier hem band, ``hidden_effect_scene``). Self-collision is off, as in the
    benchmark. Returns the positions and {"steps", "sim_time_s", "final_max_speed", "converged",
    "drape_coefficient", "edge_aniso_ke", "ignored_params", "newton_version"}.
    """
    import newton
    import warp as wp

    fabric = FabricParams.from_dict(params, source="newton_rest_state params")
    xy, faces, clamped = _scene_arrays(verts_xy, faces, clamped, "newton_rest_state")
    if mass_scale is not None and (np.shape(mass_scale) != (len(xy),) or not np.all(np.asarray(mass_scale) > 0)):
        raise ValueError(f"newton_rest_state: mass_scale must be ({len(xy)},) and positive, "
                         f"got shape {np.shape(mass_scale)}")
    z0 = None
    if seed is not None:
        z0 = np.where(clamped, 0.0, np.random.default_rng(seed).uniform(0.0, jitter_m, len(xy)))
    wp.config.quiet = True
    wp.init()
    model, solver, pipeline, material = _build(newton, wp, xy, faces, clamped, fabric, calibrate_bending, iterations,
                                               linear_iterations, False, z0, mass_scale)
    _, steps, vmax, converged, q = _drop(model, solver, pipeline, dt, rest_speed, int(np.ceil(max_time_s / dt)))
    disk_r = float(np.linalg.norm(xy[clamped], axis=1).max())
    return q, {"steps": steps, "sim_time_s": steps * dt, "final_max_speed": vmax, "converged": converged,
               "drape_coefficient": drape_coefficient(q, faces, disk_r, _flat_area(xy, faces)),
               "edge_aniso_ke": list(material.edge_aniso_ke),
               "ignored_params": [k for k in BENDING_KEYS[3:] + STRETCH_KEYS[3:] if float(getattr(fabric, k)) != 0.0],
               "newton_version": newton.__version__}


def newton_time_to_rest(
    verts_xy: Float[np.ndarray, "n 2"],
    faces: Int[np.ndarray, "m 3"],
    clamped: Bool[np.ndarray, " n"],
    params: dict,
    *,
    dt: float = 1.0 / 600.0,
    rest_speed: float = 1e-3,
    max_time_s: float = 30.0,
    iterations: int = 4,
    linear_iterations: int = 10,
    self_collision: bool = False,
    calibrate_bending: bool = True,
    repeats: int = 3,
) -> dict[str, Any]:
    """Wall time for Newton's SolverStyle3D on CPU to bring a flat Cusick specimen to rest.

    Kernels are compiled by an untimed warm-up; each of ``repeats`` runs then builds a fresh
    scene (``setup_s``, untimed in ``rest_s``) and times the stepping loop alone. If newton
    is not installed every field is None and ``reason`` says why.

    Args:
        verts_xy: flat rest positions, m, with the warp along +x.
        faces: triangles (vertex indices).
        clamped: vertices held on the support disc.
        params: fabric parameters in the drapejax flat SI schema (``FabricParams.from_dict``).
        dt: time step, s (Newton's Style3D cloth example: 60 Hz frames of 10 substeps).
        rest_speed: rest threshold on the largest particle speed, m/s.
        max_time_s: simulated time after which a run stops unconverged, s.
        iterations, linear_iterations: Style3D nonlinear and PCG iterations per step (the
            example's 4 and the ``Config`` default 10).
        self_collision: keep Style3D's cloth self-collision (off: each step is about 4x cheaper).
        calibrate_bending: match the discrete hinge energy to the strip rigidities (module docstring).
        repeats: timed runs; ``rest_s`` is their median.

    Returns:
        dict with ``rest_s`` (median wall s of the stepping loop), ``rest_s_runs``, ``setup_s``
        (median wall s to build the scene), ``sim_time_s`` (simulated s to rest), ``steps``,
        ``final_max_speed`` (m/s), ``converged``, ``drape_coefficient``, ``min_z_m`` (lowest
        point), ``max_depth_in_support_m`` (deepest free vertex inside the support cylinder),
        the solver settings and Style3D coefficients used, ``ignored_params`` (nonzero
        drapejax parameters Style3D cannot represent), sizes and versions.
    """
    fabric = FabricParams.from_dict(params, source="newton_time_to_rest params")
    xy, faces, clamped = _scene_arrays(verts_xy, faces, clamped, "newton_time_to_rest")
    if repeats < 1:
        raise ValueError(f"newton_time_to_rest: repeats must be >= 1, got {repeats}")
    try:
        import newton
        import warp as wp
    except ImportError as e:
        return _unavailable(f"newton is not installed ({e}); pip install 'drapejax[newton]'")
    wp.config.quiet = True
    wp.init()
    settings = (iterations, linear_iterations, self_collision)
    max_steps = int(np.ceil(max_time_s / dt))

    warm = _build(newton, wp, xy, faces, clamped, fabric, calibrate_bending, *settings)
    _drop(*warm[:3], dt, rest_speed, 2)
    walls, setups = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        model, solver, pipeline, material = _build(newton, wp, xy, faces, clamped, fabric, calibrate_bending, *settings)
        setups.append(time.perf_counter() - start)
        wall, steps, vmax, converged, q = _drop(model, solver, pipeline, dt, rest_speed, max_steps)
        walls.append(wall)

    disk_r = float(np.linalg.norm(xy[clamped], axis=1).max())
    r = np.linalg.norm(q[:, :2], axis=1)
    inside = ~clamped & (r < disk_r) & (q[:, 2] < 0.0)
    depth = np.minimum(disk_r - r, -q[:, 2])[inside]
    unsupported = [k for k in BENDING_KEYS[3:] + STRETCH_KEYS[3:] if float(getattr(fabric, k)) != 0.0]
    return {
        "rest_s": statistics.median(walls), "rest_s_runs": walls, "setup_s": statistics.median(setups),
        "sim_time_s": steps * dt, "steps": steps, "final_max_speed": vmax, "converged": converged,
        "drape_coefficient": drape_coefficient(q, faces, disk_r, _flat_area(xy, faces)),
        "min_z_m": float(q[:, 2].min()), "max_depth_in_support_m": float(depth.max()) if depth.size else 0.0,
        "dt": dt, "iterations": iterations, "linear_iterations": linear_iterations,
        "self_collision": self_collision, "calibrate_bending": calibrate_bending,
        "tri_aniso_ke": list(material.tri_aniso_ke), "edge_aniso_ke": list(material.edge_aniso_ke),
        "ignored_params": unsupported, "n_verts": len(xy), "n_faces": len(faces), "device": "cpu",
        "load_avg_1min": os.getloadavg()[0],
        "newton_version": newton.__version__, "warp_version": wp.__version__,
    }
