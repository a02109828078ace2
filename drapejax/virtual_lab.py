"""The virtual lab: synthetic measurements from a model richer than the one being fitted.

A drape is simulated with the base energies plus any candidate effects (``drapejax.effects``)
and written in the measurement format with ``truth.json`` (parameters, effects, mesh) so tests
and the demo can check that the diagnosis finds what was hidden. Optional: an unknown in-plane
orientation (warp angle written as null, observations rotated) and a tilted, noisy photo.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .effects import REGISTRY
from .energy import default_energies
from .io import BENDING_TESTS, READING_STD, BenchRecord, write_measurement
from .material import FabricParams, example_params
from .mesh import cusick_mesh
from .observe import height_map, silhouette
from .refine.presets import EXACT_CONFIG
from .solve import STATUS_NAMES, drape
from .solve.threads import map_side_by_side
from .solve._reuse import by_value, reuse


def simulate_with_effects(params: FabricParams, effects: dict, *, spacing_m: float = 0.02,
                          rim_spacing_m: float | None = None, seed: int = 0, buckling: bool = False):
    """Rest positions (n,3), faces and status of a Cusick drape with hidden effects {name: θ},
    dropped with the solver of ``diagnose``'s model (``refine.EXACT_CONFIG``: host sparse Cholesky
    on every backend, since CG stops short, see ``validate``). ``buckling`` caps the membrane's
    compression at the element scale (``energy.Membrane``), so that a coarse mesh folds as a
    converged one does."""
    unknown = sorted(set(effects) - set(REGISTRY))
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {sorted(REGISTRY)}")

    def build():
        mesh = cusick_mesh(spacing_m, rim_spacing_m=rim_spacing_m)
        extra = tuple(t for name, th in effects.items() for t in REGISTRY[name].terms(mesh, jnp.asarray(th, float)))
        terms = default_energies("cusick", buckling=buckling) + extra
        return mesh, jax.jit(lambda p, s: drape(mesh, p, s, terms=terms, config=EXACT_CONFIG))

    hidden = (tuple(effects), by_value([np.asarray(th, float) for th in effects.values()]))
    key = ("virtual_lab", float(spacing_m), rim_spacing_m, buckling, hidden)
    mesh, run = reuse(key, build)  # captures share a compile
    res = run(params, seed)
    return np.asarray(res.x), np.asarray(mesh.faces), STATUS_NAMES[int(res.status)]


def virtual_bench(params: FabricParams, effects: dict | None, tests: Sequence[tuple[str, str]], *, seed: int = 0,
                  std: float = READING_STD) -> list[BenchRecord]:
    """Bench readings on strips of the virtual fabric (``params`` with the hidden ``effects``
    {name: θ} a strip feels, ``Effect.strip_terms``): for each (test, direction) of ``tests``, a
    cantilever strip at Peirce's overhang 2c̄ of the fabric (rounded to the millimetre, width half
    of it), a pure bending test's loading and unloading branches at the KES-FB2 curvatures
    (``diagnose.strip``; readings ``pure_bending`` and ``pure_bending_unloading``) or a tensile test at
    ``refine.tensile.TENSILE_STRAIN`` (the simulator's membrane; no effect of the library acts on
    it). Each bending reading carries a seeded log-normal error of ``std`` as a log k1 (scaled by
    its simulated slope), each tensile reading one of ``std`` as a log force."""
    from .diagnose.strip import (KES_CURVATURES_PER_M, KES_UNLOADING_CURVATURES_PER_M, UNLOADING_TEST, ReadingResponse,
                                 StripTest)
    from .refine.tensile import TENSILE_STRAIN, tensile_force

    records = []
    for test, direction in tests:
        if test == "cantilever":
            ell = round(StripTest(params, direction).overhang_m, 3)
            records.append(BenchRecord(test, direction, {"overhang_m": ell, "width_m": ell / 2, "tip_drop_m": 1.0}))
        elif test == "pure_bending":  # the loop: its loading branch, then its unloading one
            records += [BenchRecord(test, direction, {"curvature_per_m": k, "moment_n": 1.0})
                        for k in KES_CURVATURES_PER_M]
            records += [BenchRecord(UNLOADING_TEST, direction, {"curvature_per_m": k, "moment_n": 1.0})
                        for k in KES_UNLOADING_CURVATURES_PER_M]
        elif test == "tensile":
            records.append(BenchRecord(test, direction, {"strain": TENSILE_STRAIN, "force_n_per_m": 1.0}))
        else:
            raise ValueError(f"the virtual lab makes no bench test {test!r}; expected cantilever, pure_bending (both "
                             "branches of the loop) or tensile")
    noise = std * np.random.default_rng(seed).standard_normal(len(records))
    bending = [i for i, r in enumerate(records) if r.test in BENDING_TESTS]
    logs = np.zeros(len(records))
    if bending:
        resp = ReadingResponse([records[i] for i in bending], params)
        hidden = [(REGISTRY[k], np.atleast_1d(np.asarray(v, float))) for k, v in (effects or {}).items()]
        logs[bending] = resp.values(params, hidden) + np.abs(resp.slope()) * noise[bending]
    for i, r in enumerate(records):
        if r.test == "tensile":
            logs[i] = np.log(float(tensile_force(params, r.direction, r.values["strain"]))) + noise[i]
    out = []
    for r, v in zip(records, logs):
        if not np.isfinite(v):
            raise RuntimeError(f"the virtual {r.test} strip along the {r.direction} did not come to rest")
        out.append(r.with_reading(float(np.exp(v))))
    return out


def truth_effects(effects: dict | None) -> dict:
    """Hidden effects {name: θ} as truth.json records them: {name: {"theta": [...], physical values
    (``Effect.describe``)}}."""
    out = {}
    for name, theta in (effects or {}).items():
        theta = np.atleast_1d(np.asarray(theta, float))
        out[name] = {"theta": theta.tolist(), **REGISTRY[name].describe(theta)}
    return out


def make_measurement(out_dir: str | os.PathLike, *, params: FabricParams, effects: dict | None = None,
                     spacing_m: float = 0.02, rim_spacing_m: float | None = None, seed: int = 0,
                     warp_angle_deg: float | None = 0.0, buckling: bool = False,
                     density_known: bool = True, n_px: int = 256, extent_m: float = 0.16,
                     bench: Sequence[BenchRecord] = ()) -> Path:
    """Simulate and write a virtual-lab measurement folder (with truth.json); returns its path.

    ``warp_angle_deg=None`` rotates the drape by a seeded random angle and records the warp
    angle as unknown (null), as in the real scans. ``buckling``: as ``simulate_with_effects``.
    ``bench``: bench readings of the same fabric to write beside the capture (``virtual_bench``).
    """
    effects = {k: np.atleast_1d(np.asarray(v, float)) for k, v in (effects or {}).items()}
    x, faces, status = simulate_with_effects(params, effects, spacing_m=spacing_m, rim_spacing_m=rim_spacing_m,
                                             seed=seed, buckling=buckling)
    angle = float(np.random.default_rng(seed).uniform(0, 360)) if warp_angle_deg is None else float(warp_angle_deg)
    a = np.deg2rad(angle)
    rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    truth = {"params": params.to_dict(),
             "effects": truth_effects(effects),
             "mesh": {"spacing_m": spacing_m, "rim_spacing_m": rim_spacing_m, "buckling": buckling, "seed": seed,
                      "status": status, "rotation_deg": angle}}
    return write_capture(out_dir, x @ rot.T, faces, truth=truth,
                         areal_density_kg_m2=float(params.density) if density_known else None,
                         warp_angle_deg=None if warp_angle_deg is None else angle, n_px=n_px, extent_m=extent_m,
                         bench=bench)


def make_measurements(out_dirs: Sequence[str | os.PathLike], seeds: Sequence[int], **kwargs) -> list[Path]:
    """``make_measurement`` in each of ``out_dirs`` with the drop seed beside it, the same
    ``kwargs`` (the same specimen) for all: the first alone, so that it compiles the drop
    program the others share, then the others side by side (``solve.threads.map_side_by_side``).
    The captures are those made one at a time: a drop depends on its seed alone."""
    jobs = list(zip(out_dirs, seeds, strict=True))
    if not jobs:
        return []
    make = lambda job: make_measurement(job[0], seed=job[1], **kwargs)
    return [make(jobs[0])] + map_side_by_side(make, jobs[1:], desc="virtual captures", unit="capture")


def write_capture(out_dir: str | os.PathLike, x: np.ndarray, faces: np.ndarray, *, truth: dict,
                  areal_density_kg_m2: float | None, warp_angle_deg: float | None, n_px: int = 256,
                  extent_m: float = 0.16, extra: dict | None = None, bench: Sequence[BenchRecord] = ()) -> Path:
    """Write a simulated Cusick rest state ``x`` (m, world frame) as a measurement folder: its
    silhouette, height map and scan as a capture would record them, plus ``truth`` as truth.json.
    Shared by the virtual lab and captures made by other simulators."""
    sil = silhouette(x, faces, n=n_px, extent_m=extent_m)
    hgt = np.where(sil > 0, height_map(x, faces, n=n_px, extent_m=extent_m), np.nan).astype(np.float32)
    return write_measurement(out_dir, test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                             areal_density_kg_m2=areal_density_kg_m2, warp_angle_deg=warp_angle_deg, silhouette=sil,
                             extent_m=extent_m, height=hgt, scan=(x, faces), truth=truth, extra=extra, bench=bench,
                             overwrite=True)


DEMO_EFFECTS = {"off_centre": [0.02, 0.0]}
"""The demo's hidden effect: the specimen laid 20 mm off-centre on the support disc."""

DEMO_CANDIDATES = ("off_centre", "heavy_hem")
"""The quick demo's candidate effects: the hidden one and the one whose residual it resembles most
(both shift mass outward on one side); ``drapejax demo --full`` searches every candidate."""


def default_demo_lab(out_dir: str | os.PathLike, *, captures: int = 3, spacing_m: float = 0.025) -> list[Path]:
    """The embedded demo scenario: ``captures`` drops (seeds 1, 2, ...; the fits drop with seed 0)
    of one mid-weight woven specimen with the hidden ``DEMO_EFFECTS``, in ``out_dir/capture_<i>``."""
    seeds = range(1, captures + 1)
    return make_measurements([Path(out_dir) / f"capture_{i}" for i in seeds], seeds, params=example_params("mid"),
                             effects=DEMO_EFFECTS, spacing_m=spacing_m)
