"""The jaxtyping annotations hold at run time (issue 76).

A fresh interpreter imports the mesh, material, energy and observe modules under
``jaxtyping.install_import_hook(..., "beartype.beartype")``, so every annotated function and
``eqx.Module`` of theirs checks its arguments' and results' dtypes and shapes (``Float[Array, "n 3"]``,
``Int[np.ndarray, "m 3"]``, ...) on each call, jitted code at trace time. It then builds a coarse Cusick
mesh, evaluates the default energies and their gradient, renders and describes a drape-like shape,
compares two meshes, subdivides and prolongs, and round-trips fabric parameters. A separate process
keeps the checked copies of those modules out of the other tests' module cache (their instrumented
bytecode is not written to ``__pycache__`` either: ``python -B``).

The hook is proven live by calls that the annotations reject before the function body runs (a 3-D
"silhouette" for ``rim_profile``, whose own check would raise ValueError; positions with two
coordinates for a jitted energy).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

HOOKED = ["drapejax.mesh", "drapejax.material", "drapejax.energy", "drapejax.observe"]
"""Modules (with their submodules) imported with run-time checks. ``drapejax.observe`` includes the
jitted soft renderers; ``drapejax.energy`` is checked inside ``jax.jit``/``jax.grad``/``jax.vmap``
(jaxtyping accepts tracers as ``Array``)."""

SCRIPT = r'''
import json
import sys
import time
import traceback

from jaxtyping import install_import_hook

HOOKED = json.loads(sys.argv[1])
TMP = sys.argv[2]
assert not any(m == "drapejax" or m.startswith("drapejax.") for m in sys.modules), "drapejax imported before the hook"
install_import_hook(HOOKED, "beartype.beartype")

import beartype.roar  # noqa: E402
import jax  # noqa: E402
import jaxtyping  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from drapejax import energy, material  # noqa: E402
from drapejax import mesh as meshes  # noqa: E402
from drapejax.observe import descriptors, metrics, render, soft  # noqa: E402

t0 = time.perf_counter()
hooked = sorted(n for n, m in sys.modules.items() if any(n == h or n.startswith(h + ".") for h in HOOKED)
                and type(getattr(m, "__loader__", None)).__name__ == "_JaxtypingLoader")
unhooked = sorted(n for n, m in sys.modules.items() if any(n == h or n.startswith(h + ".") for h in HOOKED)
                  and type(getattr(m, "__loader__", None)).__name__ != "_JaxtypingLoader")
failures, calls = [], []


def check(label, fn):
    """Run one exercise; a failure (a type-check error or anything else) is recorded, not fatal."""
    try:
        out = fn()
    except Exception as e:  # noqa: BLE001
        failures.append(f"{label}: {type(e).__name__}: {e}\n{traceback.format_exc(limit=-3)}")
        return None
    calls.append(label)
    return out


def rejected(label, fn):
    """``fn`` must fail with a jaxtyping/beartype type-check error (not the library's ValueError)."""
    try:
        fn()
    except (jaxtyping.TypeCheckError, beartype.roar.BeartypeCallHintViolation) as e:
        if isinstance(e, ValueError):
            failures.append(f"{label}: rejected by a ValueError, not by the type check: {e}")
        return type(e).__name__
    except Exception as e:  # noqa: BLE001
        failures.append(f"{label}: expected a type-check error, got {type(e).__name__}: {e}")
        return None
    failures.append(f"{label}: accepted an argument its annotation rejects (is the import hook off?)")
    return None


# mesh: a coarse Cusick specimen (ClothMesh's 27 annotated fields checked on construction), its
# uniform subdivision and the prolongation onto it, the other specimens and a nested hierarchy
m = check("mesh.cusick_mesh", lambda: meshes.cusick_mesh(0.03))
sub = check("mesh.subdivide", lambda: meshes.subdivide(m))
fine, prolong = sub
check("mesh.Prolongation", lambda: prolong(m.rest, fine))
check("mesh.Prolongation (jit)", lambda: jax.jit(lambda x: prolong(x, fine))(m.rest))
check("mesh.square_mesh", lambda: meshes.square_mesh(0.04))
check("mesh.strip_mesh", lambda: meshes.strip_mesh(0.1, 0.03, 0.01))
check("mesh.cusick_hierarchy", lambda: meshes.cusick_hierarchy(0.02))
check("mesh.vertex_adjacency", lambda: meshes.vertex_adjacency(np.asarray(m.faces), m.n_verts))

# material: FabricParams (every field "*b") built, round-tripped, stacked; derived quantities
p = check("material.example_params", lambda: material.example_params("mid"))
check("material.FabricParams round trip", lambda: material.FabricParams.from_dict(p.to_dict()))
json_path = f"{TMP}/mid.json"
with open(json_path, "w") as fh:
    json.dump(p.to_dict(), fh)
check("material.load_params", lambda: material.load_params(json_path))
batch = check("material.stack", lambda: material.stack([p, material.example_params("heavy")]))
check("material.unstack", lambda: material.unstack(batch))
for q, tag in ((p, ""), (batch, " (batch)")):
    check("material.validity" + tag, lambda: material.validity(q))
    check("material.plate_compliance" + tag, lambda: material.plate_compliance(q))
    check("material.plate_stiffness" + tag, lambda: material.plate_stiffness(q))
    check("material.strip_rigidity" + tag, lambda: material.strip_rigidity(q, 30.0))
    check("material.k2_directional" + tag, lambda: material.k2_directional(q))
    check("material.bending_length" + tag, lambda: material.bending_length(q, "mean"))
    check("material.gamma_cusick" + tag, lambda: material.gamma_cusick(q))
check("material.check", lambda: material.check(p))

# energy: the default terms, their total and its gradient (traced: checks run inside jit and
# grad, element functions inside vmap), and the default per-vertex Hessian blocks
terms = energy.default_energies("cusick")
x = m.rest + jnp.asarray(np.random.default_rng(0).normal(0.0, 1e-3, m.rest.shape))
value_and_grad = jax.jit(jax.value_and_grad(lambda x, p: energy.total_energy(terms, x, m, p)))
e, g = check("energy.total_energy + grad (jit)", lambda: value_and_grad(x, p))
if not (np.isfinite(float(e)) and g.shape == x.shape):
    failures.append(f"energy: value {e}, gradient shape {g.shape}")
check("energy.AbstractEnergy.hessian_blocks (jit)",
      lambda: jax.jit(lambda x: [t.hessian_blocks(x, m, p) for t in terms if type(t).hessian_blocks
                                 is energy.AbstractEnergy.hessian_blocks])(x))

# observe: a drape-like shape on the mesh (a skirt falling with six folds), rendered, described and
# compared with a second, coarser mesh of the same shape
def drape_like(mesh, folds=6):
    xy = np.asarray(mesh.rest)[:, :2]
    r, th = np.linalg.norm(xy, axis=1), np.arctan2(xy[:, 1], xy[:, 0])
    out = np.maximum(r - 0.09, 0.0)
    rr = 0.09 + out * (0.6 + 0.1 * np.cos(folds * th))
    return np.stack([rr * np.cos(th), rr * np.sin(th), -0.8 * out], 1), np.asarray(mesh.faces)


v, f = drape_like(m)
v2, f2 = drape_like(meshes.cusick_mesh(0.04))
sil = check("render.silhouette", lambda: render.silhouette(v, f, n=128))
hmap = check("render.height_map", lambda: render.height_map(v, f, n=128))
prof = check("render.rim_profile", lambda: render.rim_profile(sil))
check("render.rim_profile (boolean mask)", lambda: render.rim_profile(sil > 127))
check("render.depth_views", lambda: render.depth_views(v, f, n_views=2, size=64))
check("render.boundary_curve", lambda: render.boundary_curve(v, f))
check("render.boundary_loops", lambda: render.boundary_loops(f))
check("render.point_cloud_views", lambda: render.point_cloud_views(v, n=64))
check("render.view_axes", lambda: render.view_axes(4, 45.0, -90.0))
check("render.pixel_centres", lambda: render.pixel_centres(128, render.EXTENT_M))
dc = check("descriptors.drape_coefficient", lambda: descriptors.drape_coefficient(sil))
folds = check("descriptors.fold_count", lambda: descriptors.fold_count(prof))
check("descriptors.fold_amplitudes", lambda: descriptors.fold_amplitudes(prof))
check("descriptors.rim_spectrum", lambda: descriptors.rim_spectrum(prof))
check("descriptors.projected_area_m2", lambda: descriptors.projected_area_m2(sil))
check("descriptors.hem_heights_from_height_map", lambda: descriptors.hem_heights_from_height_map(hmap))
check("descriptors.describe_mesh", lambda: descriptors.describe_mesh(v, f, n=128))
sil2 = render.silhouette(v2, f2, n=128)
check("metrics.iou", lambda: metrics.iou(sil, sil2))
check("metrics.aligned_iou", lambda: metrics.aligned_iou(sil, sil2, step_deg=30.0, refine_deg=0.0))
check("metrics.dc_difference", lambda: metrics.dc_difference(sil, sil2))
check("metrics.spectral_distance", lambda: metrics.spectral_distance(prof, render.rim_profile(sil2, n_angles=180)))
check("metrics.rotate_about_axis", lambda: metrics.rotate_about_axis(v, 20.0, mirror=True))
scan = check("metrics.scan_distance_mm", lambda: metrics.scan_distance_mm(v, f, v2, f2, n_points=500))
check("metrics.mean_vertex_displacement_mm",
      lambda: metrics.mean_vertex_displacement_mm(v, f, v2, f2, align_rotation=False))
check("metrics.mean_relative_curvature_difference",
      lambda: metrics.mean_relative_curvature_difference(v, f, v2, f2, align_rotation=False))
check("metrics.relative_curvature_level_difference",
      lambda: metrics.relative_curvature_level_difference(v, f, v2, f2))
vj, fj = jnp.asarray(v), jnp.asarray(f)
check("soft.soft_silhouette (jit)", lambda: soft.soft_silhouette(vj, fj, sharpness=500.0, n=64, subdivisions=3))
check("soft.soft_height_map (jit)", lambda: soft.soft_height_map(vj, fj, sharpness=500.0, n=64, subdivisions=3))
check("soft.soft_rim_profile (jit)", lambda: soft.soft_rim_profile(vj, sharpness=500.0, n_angles=90))

# the hook is live: annotations reject these before the body runs
negative = {
    "render.rim_profile(3-D image)": rejected("render.rim_profile(3-D image)",
                                              lambda: render.rim_profile(np.zeros((8, 8, 3), np.uint8))),
    "jit(energy.total_energy)(x of shape (n, 2))": rejected(
        "jit(energy.total_energy)(x of shape (n, 2))",
        lambda: jax.jit(lambda x: energy.total_energy(terms, x, m, p))(x[:, :2])),
}

print(json.dumps({"hooked": hooked, "unhooked": unhooked, "calls": calls, "negative": negative,
                  "failures": failures, "dc": dc, "folds": folds, "scan_mm": scan,
                  "seconds": round(time.perf_counter() - t0, 1)}))
sys.exit(1 if failures else 0)
'''


@pytest.mark.skipif(importlib.util.find_spec("beartype") is None,
                    reason="beartype is not installed (pip install -e '.[test]' installs it)")
def test_annotations_hold_under_runtime_checks(tmp_path):
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-B", "-c", SCRIPT, json.dumps(HOOKED), str(tmp_path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    lines = proc.stdout.strip().splitlines()
    try:
        res = json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        pytest.fail(f"the checked run died (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    assert not res["failures"], "annotation checks failed:\n\n" + "\n\n".join(res["failures"])
    assert proc.returncode == 0, proc.stderr[-6000:]
    # every module the exercises touch was imported through the hook
    for name in ("drapejax.mesh", "drapejax.material", "drapejax.energy", "drapejax.energy._base",
                 "drapejax.energy.bending", "drapejax.energy.membrane", "drapejax.observe.render",
                 "drapejax.observe.descriptors", "drapejax.observe.metrics", "drapejax.observe.soft"):
        assert name in res["hooked"], (name, res)
    assert not res["unhooked"], res["unhooked"]
    assert all(res["negative"].values()), res["negative"]
    assert len(res["calls"]) >= 50, res["calls"]
    # the drape-like shape is what it was built to be: six folds, partly fallen
    assert res["folds"] == 6 and 0.0 < res["dc"] < 1.0, res
    assert 0.0 < res["scan_mm"] < 10.0, res
    print(f"{len(res['calls'])} checked calls, {len(res['hooked'])} hooked modules: "
          f"{res['seconds']} s of exercises, {time.perf_counter() - t0:.1f} s in all")
