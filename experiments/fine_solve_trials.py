"""Ways to solve the finest level's equilibrium from the prolonged coarse rest state, compared.

``drapejax simulate``'s nested drape spends most of its time in the finest level's static solve:
from the coarse drop's rest state, prolonged exactly onto the finer mesh, Newton takes 120-260
iterations of about 0.3 s each (5 mm graded to 1 mm, 3 911 vertices) while the folds migrate to
where the finer mesh puts them. This script runs the alternatives to that solve on the same
start, counts what each spends (Hessian assemblies and factorisations, gradients, energies) and
times it:

- ``static_solve``: the library's solve (``solve.static_solve`` with ``solve.FINE_CONFIG``), the
  reference;
- ``newton``: the same Newton rule in a host loop (a fresh Cholesky factorisation of the exact
  Hessian in every iteration, the least diagonal shift of a tenfold ladder where it is
  indefinite, an Armijo backtracking search), so the host-loop variants below compare with it
  at equal overheads;
- ``lagged``: the factorisation is kept while steps are taken in full (modified Newton,
  Shamanskii 1967), refreshed after a cut step;
- ``lbfgs``: L-BFGS (Nocedal 1980) whose initial inverse Hessian is the lagged factorisation, so
  the secant pairs follow how the Hessian changes between refreshes (refreshed when the line
  search halves twice or a step achieves under a tenth of its predicted decrease);
- ``geodesic``: Newton steps along the curved path x + t d + t²a/2, with a the geodesic
  acceleration of the step (Transtrum and Sethna 2012) from one extra gradient and solve, for the
  curved valley along which the folds migrate;
- ``continuation``: ``static_solve`` with the membrane's stiffness divided by ten, then with the
  fabric's own, so that the folds first migrate through a softer membrane;
- ``capped_first``: ``static_solve`` of the coarse drop's terms (the membrane's compression
  capped, ``energy.coarse_level``) on the finest mesh, then of the terms as given;
- ``drop_terms_first``: ``static_solve`` of the terms a drop's time steps use (those with
  ``in_drop``: the hourglass control left out, whose 2-ring stencils make a Newton iteration about
  three times as dear), so that the folds migrate on cheap iterations, then of the terms as given.

Each line: method, iterations, factorisations, gradients, energies, seconds (and their split),
the final energy, drape coefficient and fold count, whether the force tolerance of
``static_solve`` was reached.

    python -m experiments.fine_solve_trials --fabric mid --seeds 0,1 --out trials.jsonl
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
from cvxopt import cholmod
from cvxopt import matrix as cvx_matrix
from cvxopt import spmatrix as cvx_spmatrix

from drapejax.energy import coarse_level, default_energies, total_energy
from drapejax.material import G, example_params
from drapejax.mesh import cusick_hierarchy
from drapejax.solve import FINE_CONFIG, SolverConfig, coarsest_spacing_m, drape, static_solve, term_hessian_coo

from .common import dc_and_folds, emit

METHODS = ("static_solve", "newton", "lagged", "lbfgs", "geodesic", "continuation", "capped_first", "drop_terms_first")
SHIFT_FIRST, SHIFT_MIN = 1e-4, 1e-7


class Problem:
    """The finest level's energy, gradient and Hessian (jitted), a shifted Cholesky factorisation
    that is kept until the next one, and counters of what each costs."""

    def __init__(self, mesh, params, terms, x0):
        self.n = 3 * mesh.n_verts
        diag = 1e-6 * params.density * mesh.vertex_area
        flat = lambda x: x.reshape(-1, 3)
        self._e = jax.jit(lambda x: total_energy(terms, flat(x), mesh, params))
        self._g = jax.jit(jax.grad(lambda x: total_energy(terms, flat(x), mesh, params)))

        def coo(x):
            parts = [term_hessian_coo(t, flat(x), mesh, params, False, True) for t in terms]
            d = jnp.arange(self.n)
            return (jnp.concatenate([r for r, _, _ in parts] + [d]), jnp.concatenate([c for _, c, _ in parts] + [d]),
                    jnp.concatenate([v for _, _, v in parts] + [jnp.repeat(diag, 3)]))
        rows, cols, _ = (np.asarray(a) for a in jax.jit(coo)(x0))
        self._vals = jax.jit(lambda x: coo(x)[2])
        upper = rows <= cols
        self._upper = upper
        key = cols[upper].astype(np.int64) * self.n + rows[upper]
        ukey, self._slot = np.unique(key, return_inverse=True)
        self._diag = np.flatnonzero(ukey // self.n == ukey % self.n)
        self._mat = cvx_spmatrix(cvx_matrix(np.zeros(ukey.size)), cvx_matrix(ukey % self.n),
                                 cvx_matrix(ukey // self.n), (self.n, self.n))
        self._symbolic = None
        self.shift = 0.0
        self.ftol = float(0.1 * SolverConfig().force_tol * G * jnp.mean(params.density * mesh.vertex_area))
        self.count = {"factorisations": 0, "gradients": 0, "energies": 0, "solves": 0}
        self.seconds = {"hessian": 0.0, "factorisation": 0.0, "gradient": 0.0, "energy": 0.0, "solve": 0.0}
        for f in (self._e, self._g, self._vals):
            jax.block_until_ready(f(x0))

    def _timed(self, what, count, fn, *args):
        t = time.perf_counter()
        out = fn(*args)
        self.seconds[what] += time.perf_counter() - t
        if count:
            self.count[count] += 1
        return out

    def energy(self, x) -> float:
        return self._timed("energy", "energies", lambda y: float(self._e(jnp.asarray(y))), x)

    def grad(self, x) -> np.ndarray:
        return self._timed("gradient", "gradients", lambda y: np.asarray(self._g(jnp.asarray(y))), x)

    def factor(self, x) -> None:
        """Factorise the exact Hessian at x, shifted by the least rung of the ladder that makes it
        positive definite (the ladder starts a tenth below the last shift)."""
        vals = self._timed("hessian", None, lambda y: np.asarray(self._vals(jnp.asarray(y))), x)

        def run():
            data = np.bincount(self._slot, weights=vals[self._upper], minlength=len(self._mat.V))
            scale = np.mean(np.abs(data[self._diag]))
            first = SHIFT_FIRST if self.shift <= 0 else max(0.1 * self.shift, SHIFT_MIN)
            for mu in [0.0] + [first * 10.0 ** k for k in range(14)]:
                shifted = data.copy()
                shifted[self._diag] += mu * scale
                self._mat.V = cvx_matrix(shifted)
                if self._symbolic is None:
                    self._symbolic = cholmod.symbolic(self._mat, uplo="U")
                try:
                    cholmod.numeric(self._mat, self._symbolic)
                except ArithmeticError:
                    continue
                self.shift = mu
                return
            raise RuntimeError("no shift made the Hessian positive definite")
        self._timed("factorisation", "factorisations", run)

    def solve(self, b) -> np.ndarray:
        """The kept factorisation's solve of H y = b."""
        def run():
            out = cvx_matrix(np.asarray(b, np.float64))
            cholmod.solve(self._symbolic, out)
            return np.asarray(out).reshape(-1)
        return self._timed("solve", "solves", run)


def host_loop(prob: Problem, x0, method: str, max_iters: int, memory: int = 50,
              refresh_every: int = 0) -> tuple[np.ndarray, int, bool]:
    """Minimise from x0 by ``method`` ("newton", "lagged", "lbfgs", "geodesic"); returns the state,
    iterations and whether every force fell below the tolerance. ``refresh_every``: with "lagged"
    and "lbfgs", also refactorise after this many iterations on one factorisation (0: never)."""
    x = np.asarray(x0, np.float64).reshape(-1)
    fx, g = prob.energy(x), prob.grad(x)
    pairs: list[tuple[np.ndarray, np.ndarray]] = []
    fresh = False  # whether the kept factorisation is of the current state
    refresh = True
    it = since = 0
    while it < max_iters and np.max(np.abs(g)) >= prob.ftol:
        if refresh or method in ("newton", "geodesic"):
            prob.factor(x)
            pairs, fresh, refresh, since = [], True, False, 0
        else:
            fresh = False
        if method == "lbfgs" and pairs:  # two-loop recursion, H0⁻¹ the lagged factorisation
            q, alphas = -g.copy(), []
            for s, y in reversed(pairs):
                rho = 1.0 / np.dot(y, s)
                a = rho * np.dot(s, q)
                q -= a * y
                alphas.append((rho, a))
            d = prob.solve(q)
            for (s, y), (rho, a) in zip(pairs, reversed(alphas)):
                d += s * (a - rho * np.dot(y, d))
        else:
            d = prob.solve(-g)
        slope = float(np.dot(g, d))
        if not slope < 0:
            if fresh:
                break
            refresh = True
            continue
        acc = np.zeros_like(d)
        if method == "geodesic" and prob.shift == 0.0:
            h = 0.1
            curvature = (2.0 / h) * ((prob.grad(x + h * d) - g) / h + g)  # D³E[d, d], as H d = -g
            acc = prob.solve(-curvature)
            ratio = np.linalg.norm(acc) / max(np.linalg.norm(d), 1e-300)
            acc *= min(1.0, 1.5 / max(ratio, 1e-300))  # |a|/2 at most 0.75 |d|
        path = lambda t: x + t * d + 0.5 * t * t * acc
        t, ft, halvings = 1.0, prob.energy(path(1.0)), 0
        while halvings < 12 and not ft <= fx + 1e-4 * t * slope:
            t *= 0.5
            ft = prob.energy(path(t))
            halvings += 1
        it += 1
        if not ft <= fx:
            if fresh:
                break
            refresh = True
            continue
        x_new = path(t)
        g_new = prob.grad(x_new)
        s, y = x_new - x, g_new - g
        if method == "lbfgs" and np.dot(s, y) > 1e-16 * np.dot(y, y):
            pairs = (pairs + [(s, y)])[-memory:]
        predicted = -t * slope * (1.0 - 0.5 * t)  # the lagged model's decrease, dᵀH d = -gᵀd
        achieved = fx - ft
        since += 1
        if method == "lagged" and halvings > 0:
            refresh = True
        if refresh_every and since >= refresh_every:
            refresh = True
        if method == "lbfgs" and (halvings >= 2 or achieved < 0.1 * predicted):
            refresh = True
        x, fx, g = x_new, ft, g_new
    return x, it, bool(np.max(np.abs(g)) < prob.ftol)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fabric", default="mid", help="example fabric")
    ap.add_argument("--seeds", default="0", help="comma list of coarse drop seeds")
    ap.add_argument("--spacing-mm", type=float, default=5.0, help="finest level's interior spacing")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"comma list of: {', '.join(METHODS)}")
    ap.add_argument("--max-iters", type=int, default=2000, help="iterations of a host-loop method")
    ap.add_argument("--refresh-every", type=int, default=0, help="lagged and lbfgs: refactorise after this many "
                    "iterations on one factorisation as well (0: only on a cut step or a poor model)")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file")
    a = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    methods = a.methods.split(",")
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        ap.error(f"--methods: unknown {', '.join(unknown)}; expected some of {', '.join(METHODS)}")
    p = example_params(a.fabric)
    meshes, prolongs = cusick_hierarchy(a.spacing_mm / 1e3, coarsest_spacing_m=coarsest_spacing_m(p))
    fine = meshes[-1]
    terms = default_energies("cusick")
    coarse = jax.jit(lambda q, s: drape(meshes[0], q, s, terms=coarse_level(terms), config=SolverConfig()))
    solve = jax.jit(lambda q, y: static_solve(fine, q, y, terms=terms, config=FINE_CONFIG))
    capped = jax.jit(lambda q, y: static_solve(fine, q, y, terms=coarse_level(terms), config=FINE_CONFIG))
    in_drop = tuple(t for t in terms if t.in_drop)
    cheap = jax.jit(lambda q, y: static_solve(fine, q, y, terms=in_drop, config=FINE_CONFIG))
    softer = dataclasses.replace(p, **{k: getattr(p, k) / 10 for k in
                                       ("stretch_alpha_warp", "stretch_alpha_weft", "stretch_alpha_bias")})
    for seed in [int(s) for s in a.seeds.split(",")]:
        r = coarse(p, seed)
        x0 = r.x
        for m, pr in zip(meshes[1:], prolongs):
            x0 = pr(x0, m)
        x0 = jax.block_until_ready(x0)
        for method in methods:
            row = {"fabric": a.fabric, "seed": seed, "method": method, "verts": int(fine.n_verts),
                   "refresh_every": a.refresh_every if method in ("lagged", "lbfgs") else None,
                   "coarse_newton_iters": int(r.newton_iters)}
            if method in ("static_solve", "continuation", "capped_first", "drop_terms_first"):
                stages = {"static_solve": [(solve, p)], "continuation": [(solve, softer), (solve, p)],
                          "capped_first": [(capped, p), (solve, p)],
                          "drop_terms_first": [(cheap, p), (solve, p)]}[method]
                for fn, q in stages:  # compile first
                    jax.block_until_ready(fn(q, x0))
                t0, x, iters, split = time.perf_counter(), x0, [], []
                for fn, q in stages:
                    t1 = time.perf_counter()
                    res = jax.block_until_ready(fn(q, x))
                    x = res.x
                    iters.append(int(res.newton_iters))
                    split.append(round(time.perf_counter() - t1, 2))
                row.update(seconds=round(time.perf_counter() - t0, 2), newton_iters=sum(iters), stage_iters=iters,
                           stage_seconds=split,
                           converged=int(res.status) == 0, energy_j=float(res.energy_j))
            else:
                prob = Problem(fine, p, terms, x0.reshape(-1))
                t0 = time.perf_counter()
                x, iters, conv = host_loop(prob, x0, method, a.max_iters, refresh_every=a.refresh_every)
                row.update(seconds=round(time.perf_counter() - t0, 2), newton_iters=iters, converged=conv,
                           energy_j=prob.energy(x), **prob.count,
                           split_s={k: round(v, 2) for k, v in prob.seconds.items()})
                x = jnp.asarray(x.reshape(-1, 3))
            row["dc"], row["folds"] = dc_and_folds(x, fine)
            emit(row, a.out)


if __name__ == "__main__":
    main()
