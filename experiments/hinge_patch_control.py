r"""Per-triangle hinge shape operators with a stabilisation that vanishes for every cubic surface.

``energy.ShapeOperatorBending`` (Grinspun et al. 2006) has a 6-vertex stencil, which would make a
fine Newton iteration several times cheaper than the vertex fit with its 22-vertex hourglass
control, but on meshes of mixed vertex valence it lets a cantilever droop 5-6 % too far at any
spacing; the curvature-jump control that removes the droop stiffens a Cusick drape's fold crests
(``docs/results/2026-12-04-solver-convergence.md``). This study tries the stabilisation that page
asks for: one that charges no smooth shape up to cubic order.

For each triangle t whose three neighbours are free, the patch of t and its neighbours has up to
nine interior hinges (t's three edges, each neighbour's two others). In the small-slope limit a
hinge angle is $\theta_e = \tau_e^\top (g_{t'} - g_t)$, with $g$ the slope of the linear
interpolant on each side and $\tau_e$ the edge's in-plane normal, so the hinge angles of any
quadratic or cubic surface are $A c$ for its seven coefficients $c$ (rows fixed at rest). The
penalty is on the rest, $r = (I - A A^+)\,\theta$:

$E = \beta \sum_t \frac{A_t}{\ell_t^2} \tfrac12 \sum_e D(\tau_e)\, r_e^2$,

with $D(\tau)$ the plate's rigidity for bending across the edge and $\ell_t^2$ the squared edge of
an equilateral triangle of t's area. It is zero for every cubic surface, like the vertex fit's
hourglass control (``energy.HourglassControl``), on a 12-vertex stencil. Patches whose hinges
touch a clamped triangle are left out, and patches with fewer than eight hinges (a residual
needs more hinges than the seven coefficients).

Two studies, one JSON line per case:

- ``cantilever``: the signed relative error of H/W against the master curve
  (``validate.cantilever_case``, cut along the warp) for shape-operator bending with the control
  at each β (β = 0: without it);
- ``cusick``: the drape coefficient and fold count of "mid" on uniform Cusick meshes
  (``solve.drape``), with the Newton iterations and seconds (compilation included).

    python -m experiments.hinge_patch_control cantilever --betas 0,10,30,100 --spacings-mm 5,2.5 --gammas 1,10
    python -m experiments.hinge_patch_control cantilever --betas 0,10,30 --spacings-mm 5,2.5 --gammas 1 --width-mm 45
    python -m experiments.hinge_patch_control cusick --betas 30,100 --spacings-mm 10 --seeds 0,1
    python -m experiments.hinge_patch_control cusick --betas 10,30 --spacings-mm 7,5 --seeds 0,1
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.energy import (AbstractEnergy, Clamp, Gravity, Membrane, ShapeOperatorBending, normalize,  # noqa: E402
                             shape_operator_energies)
from drapejax.energy.bending import plate_terms  # noqa: E402
from drapejax.energy.shape_operator import edge_neighbours  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.mesh import cusick_mesh, strip_mesh  # noqa: E402
from drapejax.solve import SolverConfig, drape  # noqa: E402
from drapejax.validate import STRIP_LENGTH_M, STRIP_WIDTH_M, cantilever_case  # noqa: E402

from .common import dc_and_folds, emit  # noqa: E402

MONOMIALS = ((2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))
"""Exponents (a, b) of u^a v^b: the quadratic and cubic shapes the hinge angles of a patch can hold."""


def _slope(tri: np.ndarray, f) -> np.ndarray:
    """Gradient (2,) of the linear interpolant of f on the triangle tri (3, 2)."""
    q = f(tri)
    d = np.stack([tri[1] - tri[0], tri[2] - tri[0]])
    return np.linalg.solve(d, np.array([q[1] - q[0], q[2] - q[0]]))


def patches(faces: np.ndarray, uv: np.ndarray, clamped: np.ndarray) -> dict[str, np.ndarray]:
    """Host-side rest data of every patch (module docstring): stencil (P, 12); per hinge the
    stencil positions of its triangle's vertex opposite the edge, the edge's two ends and the far
    vertex across (P, 9, 4); the projector onto what no cubic explains (P, 9, 9); the edges'
    in-plane normals (P, 9, 2); the centre triangle's area and squared equilateral edge (P,)."""
    faces, uv, clamped = np.asarray(faces, np.int64), np.asarray(uv, float), np.asarray(clamped, bool)
    opp, tri = edge_neighbours(faces)
    held = clamped[faces].all(1)
    free = lambda u: u >= 0 and not held[u]  # noqa: E731
    rows = []
    for t in range(len(faces)):
        if held[t] or not all(free(u) for u in tri[t]):
            continue
        hinges = [(t, i) for i in range(3)]
        hinges += [(u, j) for u in tri[t] for j in range(3) if tri[u, j] != t and free(tri[u, j])]
        if len(hinges) >= 8:
            rows.append((t, hinges))
    n = len(rows)
    out = {"stencil": np.zeros((n, 12), np.int64), "hinge": np.zeros((n, 9, 4), np.int64),
           "proj": np.zeros((n, 9, 9)), "tau": np.zeros((n, 9, 2)), "area": np.zeros(n), "length2": np.zeros(n)}
    for k, (t, hinges) in enumerate(rows):
        quads = [[faces[a, i], faces[a, (i + 1) % 3], faces[a, (i + 2) % 3], opp[a, i]] for a, i in hinges]
        verts = list(dict.fromkeys(v for q in quads for v in q))
        verts += [verts[0]] * (12 - len(verts))
        out["stencil"][k] = verts
        h = len(quads)
        out["hinge"][k, :h] = [[verts.index(v) for v in q] for q in quads]
        out["hinge"][k, h:] = out["hinge"][k, 0]
        p = uv[faces[t]]
        e1, e2 = p[1] - p[0], p[2] - p[0]
        area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
        out["area"][k], out["length2"][k] = area, 4.0 * area / np.sqrt(3.0)
        c, scale = p.mean(0), np.sqrt(area)
        basis = [lambda q, a=a, b=b: ((q[:, 0] - c[0]) / scale) ** a * ((q[:, 1] - c[1]) / scale) ** b
                 for a, b in MONOMIALS]
        rows_a = np.zeros((h, len(MONOMIALS)))
        for r, (x0, x1, x2, d) in enumerate(uv[np.array(quads)]):
            e = x2 - x1
            tau = np.array([e[1], -e[0]]) / np.linalg.norm(e)
            out["tau"][k, r] = tau
            for j, f in enumerate(basis):
                rows_a[r, j] = tau @ (_slope(np.array([x2, x1, d]), f) - _slope(np.array([x0, x1, x2]), f))
        u, s, _ = np.linalg.svd(rows_a)
        q = u[:, int(np.sum(s > 1e-9 * s[0])):]
        out["proj"][k, :h, :h] = q @ q.T
    return out


def _hinge_angle(x0, x1, x2, d):
    """Signed dihedral angle at edge (x1, x2) of triangle (x0, x1, x2) with the far vertex d
    (``energy.shape_operator.hinge_angles``' convention)."""
    n = normalize(jnp.cross(x1 - x0, x2 - x0))
    nb = normalize(jnp.cross(x1 - x2, d - x2))
    return jnp.arctan2(jnp.dot(jnp.cross(n, nb), normalize(x1 - x2)), jnp.dot(n, nb))


class CubicHingeControl(AbstractEnergy):
    """The patch penalty of the module docstring (J), its rest data built for one mesh."""

    stencil: jax.Array
    hinge: jax.Array
    proj: jax.Array
    tau: jax.Array
    area: jax.Array
    length2: jax.Array
    beta: float = eqx.field(static=True, default=30.0)
    in_drop = False

    @classmethod
    def for_mesh(cls, mesh, beta: float) -> CubicHingeControl:
        data = patches(np.asarray(mesh.faces), np.asarray(mesh.uv), np.asarray(mesh.clamped))
        return cls(**{k: jnp.asarray(v) for k, v in data.items()}, beta=beta)

    def elements(self, mesh):
        return self.stencil, (self.hinge, self.proj, self.tau, self.area, self.length2)

    def element_energy(self, xe, data, params):
        hinge, proj, tau, area, length2 = data
        theta = jax.vmap(lambda q: _hinge_angle(*q))(xe[hinge])
        r = proj @ theta
        d11, d12, d22, d66 = plate_terms(params)
        t1, t2 = tau[:, 0], tau[:, 1]
        across = d11 * t1**4 + 2.0 * (d12 + 2.0 * d66) * t1**2 * t2**2 + d22 * t2**4
        return self.beta * area * 0.5 * jnp.sum(across * r * r) / length2


def cantilever(betas, spacings, gammas, width_m, out):
    for s in spacings:
        mesh = strip_mesh(STRIP_LENGTH_M, width_m, s, angle_deg=0.0, mesh_seed=0)  # cantilever_case's own mesh
        for beta in betas:
            terms = (Membrane(), ShapeOperatorBending(), Gravity(), Clamp())
            terms += (CubicHingeControl.for_mesh(mesh, beta),) if beta > 0 else ()
            for g in gammas:
                t = time.perf_counter()
                r = cantilever_case(g, 0.0, s, terms=terms, width_m=width_m)
                emit({"study": "cantilever", "beta": beta, "spacing_mm": 1e3 * s, "width_mm": 1e3 * width_m,
                      "gamma": g, "rel_err_signed": round((r["hw_sim"] - r["hw_ref"]) / r["hw_ref"], 5),
                      "converged": r["converged"], "seconds": round(time.perf_counter() - t, 1)}, out)


def cusick(betas, spacings, seeds, fabric, out):
    p = example_params(fabric)
    for s in spacings:
        mesh = cusick_mesh(s)
        for beta in betas:
            terms = shape_operator_energies("cusick", jump=False)
            terms += (CubicHingeControl.for_mesh(mesh, beta),) if beta > 0 else ()
            run = jax.jit(lambda q, seed, terms=terms: drape(mesh, q, seed, terms=terms, config=SolverConfig()))
            for seed in seeds:
                t = time.perf_counter()
                r = jax.block_until_ready(run(p, seed))
                dc, folds = dc_and_folds(r.x, mesh)
                emit({"study": "cusick", "fabric": fabric, "beta": beta, "spacing_mm": 1e3 * s, "seed": seed,
                      "verts": int(mesh.n_verts), "status": int(r.status), "newton_iters": int(r.newton_iters),
                      "dc": round(dc, 4), "folds": folds, "seconds": round(time.perf_counter() - t, 1)}, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("study", choices=("cantilever", "cusick"))
    ap.add_argument("--betas", default="0,30", help="comma list of control weights (0: without the control)")
    ap.add_argument("--spacings-mm", default="5,2.5", help="comma list of mesh spacings")
    ap.add_argument("--gammas", default="1,10", help="cantilever: comma list of gravito-bending numbers")
    ap.add_argument("--width-mm", type=float, default=1e3 * STRIP_WIDTH_M, help="cantilever: strip width")
    ap.add_argument("--seeds", default="0,1", help="cusick: comma list of drop seeds")
    ap.add_argument("--fabric", default="mid", help="cusick: example fabric")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file")
    a = ap.parse_args()
    floats = lambda text: [float(v) for v in text.split(",")]  # noqa: E731
    spacings = [v / 1e3 for v in floats(a.spacings_mm)]
    if a.study == "cantilever":
        cantilever(floats(a.betas), spacings, floats(a.gammas), a.width_mm / 1e3, a.out)
    else:
        cusick(floats(a.betas), spacings, [int(v) for v in a.seeds.split(",")], a.fabric, a.out)


if __name__ == "__main__":
    main()
