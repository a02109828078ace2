"""Simulator physics: energy invariants, implicit gradients, batching, and a Cusick drape."""

import dataclasses
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.energy import (Bending, CurvatureJumpControl, HourglassControl, Membrane, ShapeOperatorBending,
                             bending_density, default_energies, disk_sdf, total_energy)
from drapejax.energy.membrane import capped_law_energy, exp_law_energy, peak_compression as membrane_peak_compression
from drapejax.material import PARAM_KEYS, FabricParams, example_params, plate_stiffness
from drapejax.mesh import cusick_mesh, square_mesh
from drapejax.observe import drape_coefficient, fold_count, rim_profile, silhouette
from drapejax.solve import AT_REST, INVALID_PARAMS, NewtonConfig, SolverConfig, drape, drape_batch, equilibrium, \
    quick_config, static_solve

SPACING_M = 0.03
TIGHT = SolverConfig(force_tol=0.0, static=NewtonConfig(max_iters=60, step_tol_m=1e-12))


def _replace(p: FabricParams, **kw) -> FabricParams:
    """``p`` with some fields replaced, each keeping its dtype (a weakly typed Python float would
    make every jitted function taking the result compile once more)."""
    return FabricParams(**{**{k: getattr(p, k) for k in PARAM_KEYS},
                           **{k: jnp.asarray(v, dtype=jnp.result_type(getattr(p, k))) for k, v in kw.items()}})


def _rest_scalar(x):
    """Rotation-invariant scalar of a rest shape: mean height plus mean radius (m)."""
    return jnp.mean(x[:, 2]) + jnp.mean(jnp.sqrt(jnp.sum(x[:, :2] ** 2, 1)))


def _polish(mesh, params, x, iters: int = 4):
    """Plain Newton on the force balance with the exact dense Hessian (small meshes only).

    The solver's energy line search stops once energy changes reach round-off, leaving
    residual forces ~1e-11 N whose soft-mode displacement swamps finite differences; Newton on
    the gradient alone converges to round-off in the forces."""
    terms = default_energies(mesh.info.test)
    f = lambda y: total_energy(terms, y.reshape(x.shape), mesh, params)

    def step(_, y):
        return y - jnp.linalg.solve(jax.hessian(f)(y), jax.grad(f)(y))

    return jax.lax.fori_loop(0, iters, step, x.reshape(-1)).reshape(x.shape)


def _dc(x, mesh):
    sil = silhouette(np.asarray(x), np.asarray(mesh.faces), n=256, extent_m=0.16)
    return drape_coefficient(sil, 0.16, specimen_radius_m=0.15, disk_radius_m=0.09)


@pytest.fixture(scope="module")
def mesh():
    return cusick_mesh(SPACING_M)


@pytest.fixture(scope="module")
def run(mesh):
    return jax.jit(lambda p, s: drape(mesh, p, s, config=quick_config()))


@pytest.fixture(scope="module")
def mid_drape(mesh):
    """The mid-weight fabric dropped with the full solver (implicit Euler until < 1 mm/s)."""
    return jax.jit(lambda p, s: drape(mesh, p, s, config=SolverConfig()))(example_params("mid"), 0)


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


TERMS = [Membrane(), Membrane(buckling=True), Bending(), HourglassControl(), ShapeOperatorBending(),
         CurvatureJumpControl()]
TERM_IDS = ["membrane", "membrane-buckling", "bending", "hourglass", "shape-operator", "curvature-jump"]


@pytest.mark.parametrize("term", TERMS, ids=TERM_IDS)
def test_zero_energy_and_force_at_rest(mesh, term):
    p = example_params("mid")
    assert abs(float(term(mesh.rest, mesh, p))) < 1e-14
    assert float(jnp.max(jnp.abs(jax.grad(term)(mesh.rest, mesh, p)))) < 1e-12


@pytest.mark.parametrize("term", TERMS, ids=TERM_IDS)
def test_rigid_motion_invariance(mesh, term):
    p = example_params("mid")
    x = np.asarray(mesh.rest) + 0.01 * np.random.default_rng(0).normal(size=mesh.rest.shape)
    y = x @ _rotation(1).T + np.array([0.3, -0.2, 0.5])
    e0, e1 = float(term(jnp.asarray(x), mesh, p)), float(term(jnp.asarray(y), mesh, p))
    assert e0 > 0
    assert e1 == pytest.approx(e0, rel=1e-10)


def test_stretched_triangles_energy_and_force(mesh):
    """Uniform 1% warp stretch: energy α_w ε²/2 + 2·α_b(λ_b-1)²/2 per area, restoring force."""
    p = example_params("mid")
    eps = 0.01
    x = mesh.rest.at[:, 0].multiply(1.0 + eps)  # warp is along +x
    lam_bias = np.sqrt(((1 + eps) ** 2 + 1) / 2)
    density = float(p.stretch_alpha_warp) * eps**2 / 2 + float(p.stretch_alpha_bias) * (lam_bias - 1) ** 2
    assert float(Membrane()(x, mesh, p)) == pytest.approx(density * float(jnp.sum(mesh.area)), rel=1e-9)
    f = -jax.grad(Membrane())(x, mesh, p)
    rim = np.argmax(np.asarray(x[:, 0]))
    assert float(f[rim, 0]) < 0  # pulls the stretched edge back
    assert float(jnp.max(jnp.abs(f))) > 1e-3


def test_buckling_membrane_caps_compression_at_the_element_euler_load(mesh):
    """``Membrane(buckling=True)`` is the plain membrane in tension and in compression below the
    Euler load π² k1 / h² of the element-scale fold, and a constant force beyond it."""
    p, plain, capped = example_params("light"), Membrane(), Membrane(buckling=True)
    for scale in (1.01, 1.0 - 1e-7):
        x = mesh.rest.at[:, 0].multiply(scale)
        assert float(capped(x, mesh, p)) == pytest.approx(float(plain(x, mesh, p)), rel=1e-12)
    squeezed = mesh.rest.at[:, 0].multiply(0.99)
    assert 0.0 < float(capped(squeezed, mesh, p)) < 0.1 * float(plain(squeezed, mesh, p))
    alpha, eps_c = 600.0, 1e-3
    dpsi = jax.grad(capped_law_energy)
    assert float(dpsi(-0.01, alpha, 0.0, eps_c)) == pytest.approx(-alpha * eps_c, rel=1e-12)
    assert float(dpsi(-eps_c * (1 - 1e-9), alpha, 0.0, eps_c)) == pytest.approx(-alpha * eps_c, rel=1e-6)
    assert float(capped_law_energy(-0.5 * eps_c, alpha, 3.0, eps_c)) == pytest.approx(
        float(exp_law_energy(-0.5 * eps_c, alpha, 3.0)), rel=1e-12)


def test_the_membrane_compressive_force_never_falls_as_compression_grows(mesh):
    """The exponential law's compressive force α e^{βε} ε peaks at ε = -1/β; the membrane holds
    that peak beyond it (a concave energy would let elements collapse), keeps the law unchanged
    up to it, and stays finite for β ≤ 0. Checked per direction and on a squeezed mesh."""
    alpha, beta = 80.0, 12.0
    eps = jnp.linspace(-0.6, 0.05, 651)
    eps_c = membrane_peak_compression(jnp.asarray(beta))
    psi = lambda e: capped_law_energy(e, alpha, beta, eps_c)
    force = jax.vmap(jax.grad(psi))(eps)
    stiff = jax.vmap(jax.grad(jax.grad(psi)))(eps)
    assert float(eps_c) == pytest.approx(1.0 / beta)
    assert np.all(np.diff(np.asarray(force)) >= -1e-12)  # monotone force: convex energy
    assert float(jnp.min(stiff)) >= -1e-9 * alpha
    assert float(force[0]) == pytest.approx(-alpha / (beta * np.e), rel=1e-9)
    above = np.asarray(eps) > -1.0 / beta
    law = jax.vmap(lambda e: exp_law_energy(e, alpha, beta))(eps)
    np.testing.assert_allclose(np.asarray(jax.vmap(psi)(eps))[above], np.asarray(law)[above], rtol=1e-12)
    raw = np.asarray(jax.vmap(jax.grad(lambda e: exp_law_energy(e, alpha, beta)))(eps))
    assert raw[0] > 0.3 * float(force[0])  # the raw law's force has fallen to under a third there
    for b in (0.0, -0.5, -40.0):
        e_c = membrane_peak_compression(jnp.asarray(b))
        g = jax.grad(lambda e: capped_law_energy(e, alpha, b, e_c), argnums=0)(-0.3)
        assert np.isfinite(float(g)) and np.isfinite(float(capped_law_energy(-0.3, alpha, b, e_c)))
    p = dataclasses.replace(example_params("mid"), **{f"stretch_beta_{d}": jnp.asarray(beta)
                                                       for d in ("warp", "weft", "bias")})
    squeezed = mesh.rest.at[:, 0].multiply(0.7)  # warp at -0.3, bias at sqrt((0.49 + 1) / 2) - 1
    e_bias = np.sqrt((0.49 + 1.0) / 2.0) - 1.0
    per_area = (capped_law_energy(-0.3, float(p.stretch_alpha_warp), beta, 1.0 / beta)
                + 2.0 * capped_law_energy(e_bias, float(p.stretch_alpha_bias), beta, 1.0 / beta))
    assert float(Membrane()(squeezed, mesh, p)) == pytest.approx(float(per_area) * float(jnp.sum(mesh.area)),
                                                                 rel=1e-9)


def test_buckling_membrane_unlocks_the_folds_of_a_soft_fabric_on_the_fit_mesh():
    """On the default fit mesh (20 mm graded from 3 mm) the soft "light" fabric (bending length
    13 mm) locks: 2-5 folds and DC 0.61-0.66, where a uniform 5 mm mesh forms 9-11 folds and hangs
    at DC 0.33 (``experiments/cusick_convergence.py``). With the compression cap it must fold
    like the fine mesh."""
    m = cusick_mesh(0.02, rim_spacing_m=0.003)
    res = jax.jit(lambda q, s: drape(m, q, s, terms=default_energies("cusick", buckling=True),
                                     config=quick_config()))(example_params("light"), 0)
    assert int(res.status) == AT_REST
    sil = silhouette(np.asarray(res.x), np.asarray(m.faces), n=256, extent_m=0.16)
    assert fold_count(rim_profile(sil, 0.16)) >= 6
    assert _dc(res.x, m) < 0.45


def test_hourglass_control_vanishes_on_cubics_and_charges_zigzags():
    """The penalty adds no stiffness to any cubic surface (no force, exactly) but resists a
    mesh-scale zig-zag, and its Gauss–Newton Hessian is the exact one at a flat state."""
    p, term = example_params("mid"), HourglassControl()
    mesh = square_mesh(0.01, half_side_m=0.05, disk_radius_m=0.01, mesh_seed=2)
    u, v = np.asarray(mesh.uv).T
    z = 3.0 * u * u - 2.0 * u * v + 4.0 * v * v + 40.0 * u**3 - 25.0 * u * u * v + 30.0 * v**3
    cubic = jnp.asarray(np.stack([u, v, z], 1))
    assert abs(float(term(cubic, mesh, p))) < 1e-18
    assert float(jnp.max(jnp.abs(jax.grad(term)(cubic, mesh, p)))) < 1e-12
    zig = np.where(np.random.default_rng(0).random(len(u)) < 0.5, 1e-4, -1e-4)
    x = jnp.asarray(np.stack([u, v, z + zig], 1))
    assert float(term(x, mesh, p)) > 0.1 * float(Bending()(x, mesh, p) - Bending()(cubic, mesh, p))
    idx, data = term.elements(mesh)
    xe, d = mesh.rest[idx[:12]], jax.tree.map(lambda a: a[:12], data)
    exact = jax.vmap(lambda y, e: jax.hessian(term.element_energy)(y, e, p).reshape(y.size, y.size))(xe, d)
    gauss_newton = jax.vmap(lambda y, e: term.psd_element_hessian(y, e, p))(xe, d)
    np.testing.assert_allclose(np.asarray(gauss_newton), np.asarray(exact), atol=1e-12 * float(jnp.max(jnp.abs(exact))))


@pytest.mark.parametrize("phi_deg", [0.0, 30.0, 45.0, 90.0, 120.0])
def test_cylinder_bending_energy_mesh_independent(phi_deg):
    """A cylinder of curvature κ bent along φ stores ½ mᵀDm κ² + k2(φ)κ³/3 per area at two resolutions."""
    p = example_params("mid")
    kappa = 20.0
    c, s = np.cos(np.deg2rad(phi_deg)), np.sin(np.deg2rad(phi_deg))
    m = np.array([c * c, s * s, 2 * c * s])
    k2 = (float(p.bend_k2_warp) * c**4 + float(p.bend_k2_weft) * s**4
          + (4 * float(p.bend_k2_bias) - float(p.bend_k2_warp) - float(p.bend_k2_weft)) * c**2 * s**2)
    expected = 0.5 * kappa**2 * m @ np.asarray(plate_stiffness(p)) @ m + k2 * kappa**3 / 3
    for h in (0.008, 0.004):
        mesh = square_mesh(h, half_side_m=0.05, disk_radius_m=0.01, mesh_seed=3)
        uv = np.asarray(mesh.uv)
        along, across = uv @ [c, s], uv @ [-s, c]
        x = np.stack([np.sin(kappa * along) / kappa * c - across * s,
                      np.sin(kappa * along) / kappa * s + across * c,
                      (np.cos(kappa * along) - 1) / kappa], 1)
        idx, data = Bending().elements(mesh)
        e = jax.vmap(lambda xe, d: Bending().element_energy(xe, d, p))(jnp.asarray(x)[idx], data)
        area = data[1]
        cv = np.asarray(mesh.curv_verts)
        inner = (np.max(np.abs(uv[cv]), 1) < 0.05 - 2.5 * h) & ~np.asarray(mesh.clamped)[cv]
        got = float(np.sum(np.asarray(e)[inner]) / np.sum(np.asarray(area)[inner]))
        assert got == pytest.approx(expected, rel=0.02), (h, got, expected)


@pytest.mark.parametrize("phi_deg", [0.0, 30.0])
def test_arc_correction_counts_a_bend_a_spacing_wide(phi_deg):
    """A fold crest of radius equal to the mesh spacing: the quadratic fit of the chord
    under-counts its bending energy by about a fifth, the arc-corrected fit (``Bending``'s
    default) counts it within 3 %, and both agree on a gentle bend (h/ρ = 0.25)."""
    p = example_params("mid")
    h = 0.008
    mesh = square_mesh(h, half_side_m=0.05, disk_radius_m=0.01, mesh_seed=3)
    uv = np.asarray(mesh.uv)
    c, s = np.cos(np.deg2rad(phi_deg)), np.sin(np.deg2rad(phi_deg))
    cv = np.asarray(mesh.curv_verts)
    # away from the free edges and from the support disc, whose clamp holds its side flat
    inner = (np.max(np.abs(uv[cv]), 1) < 0.05 - 2.5 * h) & (np.linalg.norm(uv[cv], axis=1) > 0.01 + 2.5 * h)
    ratios = {}
    for rho in (h, 4 * h):
        along, across = uv @ [c, s], uv @ [-s, c]
        x = np.stack([rho * np.sin(along / rho) * c - across * s, rho * np.sin(along / rho) * s + across * c,
                      rho * (np.cos(along / rho) - 1)], 1)
        k = np.array([[c * c, c * s], [c * s, s * s]]) / rho
        for n in (0, 3):
            term = Bending(arc_iterations=n)
            idx, data = term.elements(mesh)
            e = np.asarray(jax.vmap(lambda xe, d: term.element_energy(xe, d, p))(jnp.asarray(x)[idx], data))
            exact = float(bending_density(jnp.asarray(k), p)) * np.sum(np.asarray(data[1])[inner])
            ratios[rho, n] = float(np.sum(e[inner]) / exact)
    assert ratios[h, 0] < 0.85, ratios
    assert ratios[h, 3] == pytest.approx(1.0, abs=0.03), ratios
    assert ratios[4 * h, 0] == pytest.approx(1.0, abs=0.02) and ratios[4 * h, 3] == pytest.approx(1.0, abs=0.01), ratios


def test_implicit_gradient_matches_finite_differences(mesh, mid_drape):
    """d(rest scalar)/d(every parameter) from the implicit adjoint vs central FD of tight static solves.

    A parameter at zero (the membrane's β) is stepped by 0.03: its derivatives are 1e-10 to 1e-11,
    and a step of 1e-3 moves the rest scalar by about 1e-13 m, where the solves' round-off
    already shows in the fourth digit."""
    p = example_params("mid")
    terms = default_energies("cusick")
    polish = jax.jit(lambda q, x: _polish(mesh, q, x, iters=5))
    x_rest = polish(p, jax.jit(lambda x: static_solve(mesh, p, x, config=TIGHT).x)(mid_drape.x))
    free = ~mesh.clamped[:, None]
    force = jax.jit(jax.grad(total_energy, 1))(terms, x_rest, mesh, p)
    assert float(jnp.max(jnp.abs(jnp.where(free, force, 0.0)))) < 1e-13
    grad = jax.jit(jax.grad(lambda q: _rest_scalar(equilibrium(mesh, q, x_rest))))(p)
    solve = lambda q: _rest_scalar(polish(q, x_rest))
    for k in PARAM_KEYS:
        v = float(getattr(p, k))
        step = 1e-4 * abs(v) if v != 0 else 3e-2
        fd = (float(solve(_replace(p, **{k: v + step}))) - float(solve(_replace(p, **{k: v - step})))) / (2 * step)
        ad = float(getattr(grad, k))
        assert abs(fd - ad) <= 1e-4 * abs(ad), (k, ad, fd)


def test_implicit_derivatives_hold_no_python_callback(mesh, mid_drape):
    """Forward and reverse derivatives of a rest state (``equilibrium`` on CPU) compile to programs
    whose only host call is the sparse solve's FFI target: JAX's persistent compilation cache
    refuses programs with Python callbacks, and a fit's soft-feature Jacobian would then compile
    again in every process."""
    scalar = lambda q: _rest_scalar(equilibrium(mesh, q, mid_drape.x))
    p = example_params("mid")
    for program in (jax.jit(jax.jacfwd(scalar)), jax.jit(jax.grad(scalar))):
        text = program.lower(p).as_text()
        assert "drapejax_solve" in text and "python_cpu_callback" not in text


def test_drop_lowers_energy_and_settles_at_static_minimum(mesh, mid_drape):
    p = example_params("mid")
    terms = default_energies("cusick")
    assert int(mid_drape.status) == AT_REST
    assert float(total_energy(terms, mid_drape.x, mesh, p)) < float(total_energy(terms, mesh.rest, mesh, p)) - 1e-3
    x_static = static_solve(mesh, p, mid_drape.x, config=TIGHT).x
    assert float(jnp.max(jnp.linalg.norm(x_static - mid_drape.x, axis=1))) < 1e-4


@pytest.mark.experiment
def test_projected_and_exact_step_hessians_reach_a_rest_state_of_the_same_physics(mesh, mid_drape):
    """The default time steps (exact Hessian where positive definite) reach rest in fewer steps
    than projected-only steps, at a static minimum whose energy and drape coefficient match the
    projected drop's (the fold pattern may differ, so the comparison is by energy and DC)."""
    p = example_params("mid")
    pr = jax.jit(lambda q, s: drape(mesh, q, s, config=SolverConfig(exact_step_hessian=False)))(p, 0)
    assert int(pr.status) == AT_REST and int(mid_drape.steps) < int(pr.steps)
    x_static = static_solve(mesh, p, pr.x, config=TIGHT).x
    assert float(jnp.max(jnp.linalg.norm(x_static - pr.x, axis=1))) < 1e-4
    assert float(pr.energy_j) == pytest.approx(float(mid_drape.energy_j), rel=0.05)
    assert _dc(pr.x, mesh) == pytest.approx(_dc(mid_drape.x, mesh), abs=0.05)


def test_sparse_solve_shifts_an_indefinite_matrix_until_positive_definite():
    """Whether the Cholesky factorisation succeeds decides exact vs shifted Newton steps: a positive
    definite matrix is solved as it is (shift 0), an indefinite one with the least shift of the
    ladder (starting a tenth below the previous shift) that makes it positive definite, and the step
    solves that system; without the ladder an indefinite matrix gives no step (the projected
    fallback takes over)."""
    from drapejax.solve._sparse import SHIFT_FIRST, sparse_solve_shifted

    rows, cols = jnp.array([0, 0, 1, 1]), jnp.array([0, 1, 0, 1])
    rhs = jnp.array([1.0, 2.0])
    for vals, previous in (([4.0, 1.0, 1.0, 3.0], 0.0), ([2.0, 1.0, 1.0, -3.0], 0.0),
                           ([2.0, 0.0, 0.0, -100.0], 0.0), ([2.0, 0.0, 0.0, -100.0], 1e3),
                           ([2.0, 0.0, 0.0, -1e-3], 1e-2)):
        a = np.array(vals).reshape(2, 2)
        y, mu = jax.jit(sparse_solve_shifted)(rows, cols, jnp.array(vals), rhs, previous)
        scale = np.mean(np.abs(np.diag(a)))
        first = SHIFT_FIRST if previous == 0 else previous / 10
        ladder = [0.0] + [first * 10.0**k for k in range(12)]
        least = next(m for m in ladder if np.all(np.linalg.eigvalsh(a + m * scale * np.eye(2)) > 0))
        assert float(mu) == pytest.approx(least, rel=1e-12) and (least == 0) is (vals[0] == 4.0)
        np.testing.assert_allclose((a + float(mu) * scale * np.eye(2)) @ np.asarray(y), rhs, atol=1e-12)
        # Without the ladder (the default solver): the exact solve where positive definite, else none.
        y0, mu0 = jax.jit(lambda v: sparse_solve_shifted(rows, cols, v, rhs, previous, False))(jnp.array(vals))
        if least == 0:
            assert float(mu0) == 0.0
            np.testing.assert_allclose(a @ np.asarray(y0), rhs, atol=1e-12)
        else:
            assert np.isinf(float(mu0)) and np.all(np.isnan(np.asarray(y0)))


@pytest.mark.parametrize("exact", [True, False])
def test_nonfinite_start_gives_a_status_not_an_exception(exact):
    """A NaN in one member's state reaches the host eigen-clamp (LAPACK raises on NaN): the drop must
    report NONFINITE, so that one bad member of a batch cannot fail the batch."""
    from drapejax.solve import NONFINITE

    m = cusick_mesh(0.03)
    x0 = m.rest.at[m.n_verts - 1, 2].set(jnp.nan)
    cfg = quick_config(exact_step_hessian=exact, exact_static_hessian=exact)
    out = jax.jit(lambda x: drape(m, example_params("mid"), 0, config=cfg, x0=x))(x0)
    assert int(out.status) == NONFINITE


@pytest.mark.parametrize("quick", [True, False])
def test_unconverged_static_solve_is_not_reported_at_rest(quick):
    """A drop that ends (by time or by speed) but whose final static solve stops short of the
    equilibrium is reported NOT_EQUILIBRIUM: its implicit gradients would be wrong."""
    from drapejax.solve import NOT_EQUILIBRIUM

    m = cusick_mesh(0.03)
    kw = dict(static=NewtonConfig(max_iters=1, step_tol_m=1e-12))
    cfg = quick_config(**kw) if quick else SolverConfig(rest_speed_m_s=10.0, **kw)
    out = jax.jit(lambda q: drape(m, q, 0, config=cfg))(example_params("mid"))
    assert int(out.status) == NOT_EQUILIBRIUM and np.all(np.isfinite(np.asarray(out.x)))


def test_static_solve_reports_a_status_per_member(mesh, mid_drape):
    """Batched static solves never raise: a member at its equilibrium is AT_REST, an impossible
    one INVALID_PARAMS, and a solve cut short NOT_EQUILIBRIUM (its implicit gradients would be wrong)."""
    from drapejax.solve import NOT_EQUILIBRIUM

    p = example_params("mid")
    bad = _replace(p, density=-p.density)
    batch = FabricParams(**{k: jnp.stack([getattr(p, k), getattr(bad, k)]) for k in PARAM_KEYS})
    out = jax.jit(jax.vmap(lambda q: static_solve(mesh, q, mid_drape.x, config=TIGHT)))(batch)
    assert np.asarray(out.status).tolist() == [AT_REST, INVALID_PARAMS]
    assert float(jnp.max(jnp.linalg.norm(out.x[0] - mid_drape.x, axis=1))) < 1e-4
    short = SolverConfig(force_tol=0.0, static=NewtonConfig(max_iters=1, step_tol_m=1e-15))
    heavier = _replace(p, density=2 * p.density)
    assert int(jax.jit(lambda q: static_solve(mesh, q, mid_drape.x, config=short))(heavier).status) == NOT_EQUILIBRIUM


def test_sparse_solve_reuses_patterns_correctly():
    """The cached orderings and numeric refactorisations give the dense answer when values change
    on one pattern (duplicates summed), when two patterns alternate, and when a matrix is
    indefinite (the Cholesky factorisation fails and LDLᵀ solves it)."""
    from drapejax.solve._sparse import sparse_solve

    rng = np.random.default_rng(0)

    def pattern(n, e):
        idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(e)])
        rows = np.repeat(idx, 3, axis=1).reshape(-1)
        cols = np.tile(idx, (1, 3)).reshape(-1)
        return np.concatenate([rows, np.arange(n)]), np.concatenate([cols, np.arange(n)])

    solve = jax.jit(sparse_solve)
    patterns = [pattern(12, 20), pattern(15, 25)]
    for step in range(6):
        rows, cols = patterns[step % 2]
        n = int(rows.max()) + 1
        vals = rng.normal(size=rows.size)
        dense = np.zeros((n, n))
        np.add.at(dense, (rows, cols), vals)
        signs = np.where(np.arange(n) % 2 & (step >= 2), -1.0, 1.0)
        dense = 0.5 * (dense + dense.T) + 3 * n * np.diag(signs)
        sym_vals = dense[rows, cols] / np.bincount(rows * n + cols, minlength=n * n)[rows * n + cols]
        rhs = rng.normal(size=n)
        y = solve(jnp.array(rows), jnp.array(cols), jnp.array(sym_vals), jnp.array(rhs))
        np.testing.assert_allclose(dense @ np.asarray(y), rhs, atol=1e-10)


@jax.jit
def _energy_hessian(terms, x, mesh, params):
    """Dense Hessian of the total energy at rest positions x (n,3), in one compiled program
    (evaluated eagerly, every primitive compiled on its own: 50 s against 8 s at 15 mm)."""
    return jax.hessian(lambda y: total_energy(terms, y.reshape(x.shape), mesh, params))(x.reshape(-1))


def test_assembled_hessian_is_the_autodiff_hessian(mesh):
    """The sparse Newton matrix, summed per vertex pair on the device (``solve._sparse.stencil_coo``),
    is the dense autodiff Hessian of the total energy at a folded state, to rounding, and
    symmetric; summing cuts the entries that leave the device by more than half."""
    from drapejax.solve._sparse import element_hessians, hessian_coo

    p, terms = example_params("mid"), default_energies("cusick")
    x = mesh.rest + 4e-3 * jnp.asarray(np.random.default_rng(5).normal(size=mesh.rest.shape))
    n = 3 * mesh.n_verts
    rows, cols, vals = (np.asarray(a) for a in hessian_coo(terms, x, mesh, p, jnp.zeros(mesh.n_verts), project=False,
                                                           exact=True))
    assembled = np.zeros((n, n))
    np.add.at(assembled, (rows, cols), vals)
    dense = np.asarray(_energy_hessian(terms, x, mesh, p))
    np.testing.assert_allclose(assembled, dense, atol=1e-9 * np.abs(dense).max())
    np.testing.assert_allclose(assembled, assembled.T, atol=1e-13 * np.abs(dense).max())
    entries = sum(element_hessians(t, x, mesh, p, False, True)[1].size for t in terms)
    assert vals.size < 0.5 * entries, (vals.size, entries)


def test_closed_over_meshs_hessian_positions_are_trace_time_constants(mesh):
    """In a compiled program over a closed-over mesh, every term's triplet positions are
    constants of the trace, summed per vertex pair: the sparse solve then binds its pattern once
    (``solve._sparse._host``) instead of receiving and comparing the positions at every call, and
    fewer entries leave the device."""
    from drapejax.solve._sparse import element_hessians, term_hessian_coo

    p, terms = example_params("mid"), default_energies("cusick")
    seen = {}

    def assemble(x):
        for t in terms:
            rows, _, vals = term_hessian_coo(t, x, mesh, p, project=False, exact=True)
            idx, blocks = element_hessians(t, x, mesh, p, False, True)
            shared = idx.shape[1] > 1  # stencils of several vertices share vertex pairs
            seen[type(t).__name__] = (isinstance(rows, np.ndarray), vals.size < blocks.size or not shared)
        return x

    jax.jit(assemble).lower(mesh.rest)
    assert seen and all(const and summed for const, summed in seen.values()), seen


def test_static_solve_ends_at_a_minimum_not_a_saddle(mesh, run):
    """Exact Newton steps are only taken where the Hessian is positive definite: the rest state
    of a soft fabric after the short quick-config drop has a positive definite Hessian."""
    p = _replace(example_params("mid"), bend_k1_warp=0.3 * example_params("mid").bend_k1_warp)
    res = run(p, 3)
    assert int(res.status) == AT_REST
    h = _energy_hessian(default_energies("cusick"), res.x, mesh, p)
    assert float(np.linalg.eigvalsh(np.asarray(h))[0]) > 0.0


def test_newton_retries_a_failed_exact_step_with_the_projected_one():
    """f = (x² - 1)² started where f'' is positive but tiny: the exact Newton step is ~10⁶ long
    and fails every backtracking halving. The solve must go on with the fallback direction and
    reach the minimum at x = 1 instead of stopping at its start."""
    from drapejax.solve._newton import newton_minimise

    f = lambda x: jnp.sum((x**2 - 1.0) ** 2)
    x0 = jnp.array([1.0 / np.sqrt(3.0) + 1e-7])

    def direction(x, g, exact, shift):
        d = jnp.where(exact, -g / jax.hessian(f)(x)[0, 0], -0.1 * g)
        return d, 1, exact, shift

    x, iters, _, conv = newton_minimise(f, x0, direction, NewtonConfig(max_iters=200), force_tol=1e-10)
    assert bool(conv) and abs(float(x[0]) - 1.0) < 1e-8, (x, iters)


@pytest.mark.experiment
def test_rim_graded_cusick_mesh_resolves_the_bend_over_the_disc_edge():
    """The skirt's bend over the disc edge is a boundary layer narrower than 10 mm. A uniform
    20 mm mesh hinges there cheaply and droops too far; grading its rings from 3 mm at the edge
    must at least halve the error of its drape coefficient (mean over three drop seeds) against
    a 10 mm mesh graded from 2 mm, which matches a uniform 5 mm mesh at half its vertices."""
    p = example_params("mid")
    dc = {}
    for key, h, rim, seeds in (("uniform", 0.02, None, 3), ("graded", 0.02, 0.003, 3), ("fine", 0.01, 0.002, 1)):
        m = cusick_mesh(h, rim_spacing_m=rim)
        run = jax.jit(lambda q, s: drape(m, q, s, config=quick_config()))
        vals = []
        for s in range(seeds):
            res = run(p, s)
            assert int(res.status) == AT_REST, (key, s)
            vals.append(_dc(res.x, m))
        dc[key] = float(np.mean(vals))
    assert m.n_verts < 0.5 * cusick_mesh(0.005).n_verts
    err = {k: abs(dc[k] - dc["fine"]) for k in ("uniform", "graded")}
    assert err["graded"] < 0.5 * err["uniform"], dc


@pytest.mark.experiment
def test_cg_drop_reaches_rest_at_a_minimum_on_prior_fabrics():
    """The device (CG) path: on two prior fabrics at 15 mm that truncated (Steihaug) PCG left
    short of rest after the quick drop (its static solve stalled on linearly convergent
    truncated steps), exact-Hessian PCG with a projected-Hessian fallback at negative
    curvature reaches rest, and at a minimum (positive definite Hessian)."""
    from drapejax.inverse.prior import default_prior

    fine = cusick_mesh(0.015)
    prior = default_prior().sample(8, 0)
    run_cg = jax.jit(lambda q, s: drape(fine, q, s, config=quick_config(linear_solver="cg")))
    terms = default_energies("cusick")
    for i in (1, 7):
        p = jax.tree.map(lambda a: a[i], prior)
        res = run_cg(p, i)
        assert int(res.status) == AT_REST, i
        h = _energy_hessian(terms, res.x, fine, p)
        assert float(np.linalg.eigvalsh(np.asarray(h))[0]) > 0.0, i


_TWO_CPU_DEVICES = """
import json, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from drapejax.validate import TERMS
from drapejax.material import PARAM_KEYS, FabricParams, example_params
from drapejax.mesh import cusick_mesh, strip_mesh
from drapejax.solve import _reuse, drape, drape_batch, quick_config
mesh, mid = cusick_mesh(%r), example_params("mid")
members = [mid, FabricParams(**{**{k: getattr(mid, k) for k in PARAM_KEYS}, "density": jnp.asarray(-0.1)}),
           FabricParams(**{**{k: getattr(mid, k) for k in PARAM_KEYS}, "density": 1.3 * mid.density})]
batch, seeds = FabricParams(**{k: jnp.stack([getattr(q, k) for q in members]) for k in PARAM_KEYS}), jnp.arange(3)
res = {"devices": jax.local_device_count()}
for name, m, terms, cfg in (("direct", mesh, None, quick_config()),
                            ("cg", strip_mesh(0.1, 0.015, 0.01), TERMS, quick_config(linear_solver="cg"))):
    _reuse._CACHE.clear()
    out = drape_batch(m, batch, seeds, terms=terms, config=cfg)
    solo = jax.jit(lambda p, s: drape(m, p, s, terms=terms, config=cfg))
    dx = [float(np.abs(np.asarray(out.x[i]) - np.asarray(solo(members[i], i).x)).max()) for i in (0, 2)]
    shards = max(k[5] for k in _reuse._CACHE if k[0] == "drape_batch")
    res[name] = {"status": np.asarray(out.status).tolist(), "shards": shards, "dx": max(dx)}
print(json.dumps(res))
"""


@pytest.mark.experiment
def test_batch_on_several_cpu_devices_stays_on_one():
    """Two (forced) CPU devices. A CPU program holds host callbacks (direct sparse solves, the CG
    fallback's element-Hessian projection), which deadlock inside a program sharded over CPU
    devices, so both solvers keep the batch on one device; the members equal the single drapes
    and the impossible member stays isolated. (Sharding over accelerators is not testable here.)"""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", _TWO_CPU_DEVICES % SPACING_M], env=env, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["devices"] == 2
    for name in ("direct", "cg"):
        assert res[name]["shards"] == 1 and res[name]["status"] == [AT_REST, INVALID_PARAMS, AT_REST], res
        assert res[name]["dx"] < 1e-6, res


def test_mid_cusick_folds_disc_and_dc_trends(mesh, mid_drape):
    p = example_params("mid")
    x = mid_drape.x
    sil = silhouette(np.asarray(x), np.asarray(mesh.faces), n=256, extent_m=0.16)
    assert 4 <= fold_count(rim_profile(sil, 0.16)) <= 12
    free = ~np.asarray(mesh.clamped)
    assert float(np.min(np.asarray(disk_sdf(x, 0.09, 0.005, 0.001))[free])) >= 0.0
    dc = _dc(x, mesh)
    heavier = static_solve(mesh, _replace(p, density=2 * p.density), x).x
    stiffer = static_solve(mesh, _replace(p, bend_k1_warp=3 * p.bend_k1_warp, bend_k1_weft=3 * p.bend_k1_weft,
                                          bend_k1_bias=3 * p.bend_k1_bias), x).x
    assert _dc(heavier, mesh) < dc - 0.01
    assert _dc(stiffer, mesh) > dc + 0.01


@pytest.mark.parametrize("strategy", [pytest.param("vmap", marks=pytest.mark.experiment), "map"])
def test_batch_equals_loop_and_impossible_member_is_isolated(mesh, run, strategy):
    mid = example_params("mid")
    members = [mid, _replace(mid, density=-0.1), _replace(mid, density=1.3 * mid.density)]
    batch = FabricParams(**{k: jnp.stack([getattr(q, k) for q in members]) for k in PARAM_KEYS})
    seeds = jnp.array([0, 1, 2])
    out = drape_batch(mesh, batch, seeds, config=quick_config(), strategy=strategy)
    assert np.asarray(out.status).tolist()[1] == INVALID_PARAMS
    for i in (0, 2):
        solo = run(members[i], seeds[i])
        assert int(out.status[i]) == int(solo.status) == AT_REST
        # 1 µm: a soft fold mode converges slowly
        np.testing.assert_allclose(np.asarray(out.x[i]), np.asarray(solo.x), atol=1e-6)
    # A second batch on the same mesh and settings reuses the compiled program (dataset shards):
    # nothing is compiled for it. (Counted rather than read from the jitted runner's cache size,
    # which jax's global cache can evict in a long test session.)
    compiles = []
    listener = lambda event, secs, **kw: compiles.append(event) if event.endswith("/backend_compile_duration") else None
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        again = drape_batch(mesh, batch, seeds, config=quick_config(), strategy=strategy)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiles == []
    np.testing.assert_array_equal(np.asarray(again.x), np.asarray(out.x))


@pytest.mark.experiment
def test_shifted_steps_reach_the_equilibrium_of_the_same_physics():
    """Shifted steps (``SolverConfig.shifted_steps``, the default) change only the way to rest:
    the drape ends at rest, at a state where the unshifted static solve finds no force to remove."""
    m = cusick_mesh(0.03)
    p = example_params("mid")
    out = jax.jit(lambda q: drape(m, q, 0, config=quick_config(linear_solver="direct")))(p)
    assert int(out.status) == AT_REST
    x = static_solve(m, p, out.x, config=quick_config(shifted_steps=False, linear_solver="direct")).x
    assert float(jnp.max(jnp.abs(x - out.x))) < 1e-6


def test_an_element_hessian_lapack_cannot_decompose_comes_back_as_nan_not_an_error(monkeypatch):
    """A batch of element Hessians on the host in which LAPACK fails for one matrix (as it did for
    finite entries of extreme magnitude in a soft prior fabric's drop): that matrix comes back NaN
    (the solver then reports a non-finite state) and the others projected as usual."""
    from drapejax.solve import _sparse

    real = _sparse._psd_chunk

    def failing(h, xp=np, absolute=False):
        if np.any(np.asarray(h)[..., 0, 0] == 123.0):
            raise np.linalg.LinAlgError("Eigenvalues did not converge")
        return real(h, xp, absolute)

    monkeypatch.setattr(_sparse, "_psd_chunk", failing)
    h = np.asarray(jax.random.normal(jax.random.PRNGKey(1), (6, 9, 9), jnp.float64))
    h = h + np.swapaxes(h, 1, 2)
    h[3, 0, 0] = 123.0
    out = np.asarray(_sparse._psd_host(h))
    assert np.isnan(out[3]).all() and np.isfinite(np.delete(out, 3, 0)).all()
    np.testing.assert_allclose(np.linalg.eigvalsh(np.delete(out, 3, 0)),
                               np.maximum(np.linalg.eigvalsh(np.delete(h, 3, 0)), 0), atol=1e-10)


@pytest.mark.experiment
def test_absolute_membrane_steps_reach_the_equilibrium_of_the_same_physics():
    """``Direct(absolute=True)`` changes only the matrix of indefinite steps: the membrane's element
    Hessians by their eigenvalues' magnitudes (the same eigenvectors), every other term exact. A
    drape with it ends at rest where the default static solve finds no force to remove."""
    from drapejax.solve import Direct
    from drapejax.solve._sparse import psd_project

    h = jax.random.normal(jax.random.PRNGKey(0), (4, 9, 9), jnp.float64)
    h = h + jnp.swapaxes(h, 1, 2)
    w = np.linalg.eigvalsh(np.asarray(h))
    np.testing.assert_allclose(np.linalg.eigvalsh(np.asarray(psd_project(h, absolute=True))), np.sort(np.abs(w), 1),
                               atol=1e-10)
    np.testing.assert_allclose(np.linalg.eigvalsh(np.asarray(psd_project(h))), np.maximum(w, 0), atol=1e-10)
    assert Membrane.element_instability and not Bending.element_instability
    m = cusick_mesh(0.03)
    p = example_params("mid")
    for solver in (Direct(absolute=True), SolverConfig(absolute_above=1e-5, linear_solver="direct").newton_solve()):
        out = jax.jit(lambda q, c=quick_config(linear_solver=solver): drape(m, q, 0, config=c))(p)
        assert int(out.status) == AT_REST
        x = static_solve(m, p, out.x, config=quick_config(linear_solver="direct")).x
        assert float(jnp.max(jnp.abs(x - out.x))) < 1e-6
    assert SolverConfig(absolute_above=1e-5, linear_solver="direct").newton_solve() == Direct(
        absolute=True, absolute_above=1e-5)


def test_the_absolute_rule_waits_for_a_shift_above_its_threshold():
    """``Direct(absolute=True, absolute_above=T)``: the shift ladder on the exact matrix stops at T
    (``ceiling``), so a matrix that a shift below T makes positive definite keeps its exact
    curvature and one that needs more is left to the absolute rule."""
    from drapejax.solve._sparse import sparse_solve_shifted

    n = 6
    d = jnp.asarray([1.0, 1.0, 1.0, 1.0, 1.0, -2e-3])  # mean |diag| ~1: needs a shift just above 2e-3
    rows = cols = jnp.arange(n)
    rhs = jnp.ones(n)
    _, mu = sparse_solve_shifted(rows, cols, d, rhs, 0.0, True)
    assert 2e-3 < float(mu) <= 1e-1
    _, capped = sparse_solve_shifted(rows, cols, d, rhs, 0.0, True, 1e-3)
    assert not np.isfinite(float(capped))
    _, enough = sparse_solve_shifted(rows, cols, d, rhs, 0.0, True, 1e-1)
    assert float(enough) == float(mu)


def test_the_coarsest_level_drops_with_each_terms_coarse_level():
    """``drape_multilevel``'s coarse drop runs each term's ``coarse_level()``: the membrane's is
    capped in compression, every other default term is itself; a drape whose coarse terms are
    already capped is unchanged by the default. The finest level is solved with the terms as given:
    here the coarsest level is the finest, so its capped rest state is solved again without the cap.
    (That the cap moves the coarse drop is
    ``test_buckling_membrane_unlocks_the_folds_of_a_soft_fabric_on_the_fit_mesh``.)"""
    from drapejax.energy import coarse_level, default_energies
    from drapejax.mesh import nested_cusick_meshes
    from drapejax.solve import drape_multilevel

    terms = default_energies("cusick")
    assert Membrane().coarse_level() == Membrane(buckling=True)
    assert [t.coarse_level() is t for t in terms] == [not isinstance(t, Membrane) for t in terms]
    meshes, _ = nested_cusick_meshes(0.04, 1)
    p = example_params("mid")
    run = jax.jit(lambda s, coarse: drape_multilevel(meshes, (), p, s, coarse_terms=coarse))
    default = jax.jit(lambda s: drape_multilevel(meshes, (), p, s))(0)
    capped = run(0, coarse_level(terms))
    np.testing.assert_array_equal(np.asarray(default.coarse_x), np.asarray(capped.coarse_x))
    assert int(default.finest.status) == AT_REST
    assert int(static_solve(meshes[0], p, default.finest.x).newton_iters) <= 1
    assert float(jnp.max(jnp.abs(default.finest.x - default.coarse_x))) > 1e-6  # solved again without the cap


def test_linear_solver_names_and_types_select_the_same_solver(monkeypatch):
    """``SolverConfig.linear_solver`` by name or by type resolves to one solver type, "auto" by
    backend; an unknown name raises on construction and names the field."""
    from drapejax.refine import EXACT_CONFIG as refine_exact
    from drapejax.solve import CG, EXACT_CONFIG, Direct
    from drapejax.solve.drop import linear_solver

    assert SolverConfig(linear_solver="direct").newton_solve() == Direct() == Direct(shifted=True)
    assert SolverConfig(linear_solver="direct", shifted_steps=False).newton_solve() == Direct(shifted=False)
    assert SolverConfig(linear_solver="cg").newton_solve() == CG()
    for solver in (Direct(), Direct(shifted=False), CG()):
        assert SolverConfig(linear_solver=solver).newton_solve() == solver
        assert linear_solver(SolverConfig(linear_solver=solver)) == solver.name
    for backend, want in (("cpu", Direct(shifted=False)), ("gpu", CG())):
        monkeypatch.setattr(jax, "default_backend", lambda: backend)
        assert SolverConfig(shifted_steps=False).newton_solve() == want
    assert refine_exact is EXACT_CONFIG and EXACT_CONFIG.newton_solve() == quick_config(
        linear_solver="direct").newton_solve()
    with pytest.raises(ValueError, match="linear_solver 'cholesky'"):
        SolverConfig(linear_solver="cholesky")


def test_solver_refuses_float32_with_one_clear_error():
    """In float32 every drape would end short of rest; ``drape``, ``static_solve`` and
    ``equilibrium`` say so instead (a fresh process: the suite itself runs in float64)."""
    code = ("import jax\n"
            "from drapejax.material import example_params\n"
            "from drapejax.mesh import cusick_mesh\n"
            "from drapejax.solve import drape, equilibrium, static_solve\n"
            "m, p = cusick_mesh(0.03), example_params('mid')\n"
            "for name, call in (('drape', lambda: drape(m, p, 0)), "
            "('static_solve', lambda: static_solve(m, p, m.rest)),\n"
            "                   ('equilibrium', lambda: equilibrium(m, p, m.rest))):\n"
            "    try:\n"
            "        call()\n"
            "    except ValueError as e:\n"
            "        print('refused', e)\n")
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert [ln.split()[1] for ln in lines] == ["drape:", "static_solve:", "equilibrium:"], out.stdout
    assert all("jax_enable_x64" in ln for ln in lines)


def test_subdivision_nests_the_mesh_and_prolongation_adds_no_membrane_strain():
    """A uniform subdivision halves the spacing, keeps the clamp set and area, and a coarse
    shape carried onto it by the prolongation has the coarse membrane energy exactly (each
    child triangle carries its parent's deformation gradient)."""
    from drapejax.mesh import strip_mesh, subdivide

    coarse = strip_mesh(0.12, 0.03, 0.01)
    fine, prolong = subdivide(coarse)
    assert fine.n_faces == 4 * coarse.n_faces
    assert fine.info.spacing_m == pytest.approx(0.5 * coarse.info.spacing_m)
    np.testing.assert_allclose(float(jnp.sum(fine.area)), float(jnp.sum(coarse.area)), rtol=1e-12)
    u = coarse.rest[:, 0]
    bent = coarse.rest + jnp.stack([0.05 * u**2, 0.02 * u * coarse.rest[:, 1], -0.3 * u**2], 1)
    bent = jnp.where(coarse.clamped[:, None], coarse.rest, bent)
    p = example_params("mid")
    e_coarse, e_fine = Membrane()(bent, coarse, p), Membrane()(prolong(bent, fine), fine, p)
    assert float(e_coarse) > 1e-6
    np.testing.assert_allclose(float(e_fine), float(e_coarse), rtol=1e-10)
    cusick, fine_c = cusick_mesh(0.03), subdivide(cusick_mesh(0.03))[0]
    r = np.linalg.norm(np.asarray(fine_c.rest)[:, :2], axis=1)
    assert np.isclose(r.max(), 0.15) and np.all(r[np.asarray(fine_c.clamped)] <= 0.09 + 1e-12)
    ring = np.isclose(r, 0.09, atol=1e-12)
    assert ring.sum() == 2 * np.isclose(np.linalg.norm(np.asarray(cusick.rest)[:, :2], axis=1), 0.09, atol=1e-12).sum()


def test_multilevel_drape_ends_at_the_fine_meshs_equilibrium():
    """The coarse drop carried onto the nested fine mesh and solved there is at rest and a static
    equilibrium of the fine mesh (a further static solve takes at most one Newton iteration)."""
    from drapejax.mesh import nested_cusick_meshes
    from drapejax.solve import drape_multilevel

    meshes, prolongs = nested_cusick_meshes(0.04, 2)
    p = example_params("mid")
    r = jax.jit(lambda s: drape_multilevel(meshes, prolongs, p, s))(0)
    assert r.level_status.tolist() == [AT_REST, AT_REST] and int(r.finest.status) == AT_REST
    assert r.finest.x.shape == (meshes[1].n_verts, 3)
    assert int(r.finest.newton_iters) == int(jnp.sum(r.level_newton_iters))
    again = static_solve(meshes[1], p, r.finest.x)
    assert int(again.status) == AT_REST and int(again.newton_iters) <= 1
    assert 0.3 < float(_dc(r.finest.x, meshes[1])) < 0.95


def test_a_fine_level_at_rest_is_reported_at_rest_whatever_the_coarse_level_reached():
    """A coarse drop whose own static solve ran out of iterations is a start, not the result: the
    fine level's converged solve makes the finest state a static equilibrium, so the drape is
    ``AT_REST`` (as ``drape`` reports the converged final solve of a drop that used its step
    budget), and the coarse level keeps its own status in ``level_status``."""
    import dataclasses

    from drapejax.mesh import nested_cusick_meshes
    from drapejax.solve import NOT_EQUILIBRIUM, SolverConfig, drape_multilevel
    from drapejax.solve._newton import NewtonConfig

    meshes, prolongs = nested_cusick_meshes(0.04, 2)
    p = example_params("mid")
    short = dataclasses.replace(SolverConfig(), static=NewtonConfig(max_iters=1, step_tol_m=1e-9))
    r = jax.jit(lambda s: drape_multilevel(meshes, prolongs, p, s, coarse_config=short))(0)
    assert r.level_status.tolist() == [NOT_EQUILIBRIUM, AT_REST] and int(r.finest.status) == AT_REST
    again = static_solve(meshes[1], p, r.finest.x)
    assert int(again.status) == AT_REST and int(again.newton_iters) <= 1


@pytest.mark.parametrize("spacing, rim, levels, coarse", [(0.005, None, 3, (0.02, 0.004)),
                                                          (0.01, 0.003, 2, (0.02, 0.006)),
                                                          (0.02, None, 1, (0.02, 0.004)),
                                                          (0.03, 0.01, 1, (0.03, 0.01))])
def test_cusick_hierarchy_names_its_finest_level(spacing, rim, levels, coarse):
    """``cusick_hierarchy(spacing, rim)`` ends on a mesh with that interior spacing; its coarsest
    level is the rim-graded mesh at the largest power-of-two multiple not above 20 mm (rim spacing
    a fifth of the interior one unless given), and each level subdivides the one before."""
    from drapejax.mesh import cusick_hierarchy, cusick_mesh

    meshes, prolongs = cusick_hierarchy(spacing, rim)
    assert len(meshes) == levels and len(prolongs) == levels - 1
    assert meshes[-1].info.spacing_m == pytest.approx(spacing)
    assert meshes[0] is cusick_mesh(coarse[0], rim_spacing_m=coarse[1])
    for coarse_m, fine_m in zip(meshes[:-1], meshes[1:]):
        assert fine_m.faces.shape[0] == 4 * coarse_m.faces.shape[0]


def test_coarsest_level_scales_with_the_bending_length_and_is_defined_for_invalid_parameters():
    """``solve.coarsest_spacing_m``: 0.75 bending lengths, capped at ``mesh.COARSEST_SPACING_M``;
    parameters without a finite bending length (a NaN or negative rigidity) get the cap, not a
    NaN that would reach the mesh builder."""
    from drapejax.material import bending_length
    from drapejax.mesh import COARSEST_SPACING_M
    from drapejax.solve.multilevel import COARSEST_OVER_BENDING_LENGTH, coarsest_spacing_m

    light = example_params("light")
    soft = dataclasses.replace(light, **{k: getattr(light, k) / 30 for k in ("bend_k1_warp", "bend_k1_weft",
                                                                           "bend_k1_bias")})
    expected = COARSEST_OVER_BENDING_LENGTH * float(bending_length(soft, "mean"))
    assert expected < COARSEST_SPACING_M
    assert coarsest_spacing_m(soft) == pytest.approx(expected)
    stiff = dataclasses.replace(light, **{k: getattr(light, k) * 30 for k in ("bend_k1_warp", "bend_k1_weft",
                                                                            "bend_k1_bias")})
    assert coarsest_spacing_m(stiff) == COARSEST_SPACING_M
    for bad in (float("nan"), -1e-6):
        assert coarsest_spacing_m(dataclasses.replace(light, bend_k1_warp=bad)) == COARSEST_SPACING_M


def test_finest_level_is_refined_for_a_fabric_whose_folds_a_5mm_mesh_would_lock():
    """``solve.finest_spacing_m``: 5 mm for the embedded fabrics; a fabric as stiff in bending
    but thirteen times lighter (so thirteen times the ``locking_number``) gets a finer level whose
    locking number is the bound, and a heavier membrane or a lower density only ever refines it;
    parameters outside the model's range keep the default."""
    from drapejax.solve import DEFAULT_FINEST_SPACING_M, LOCKING_NUMBER_MAX, finest_spacing_m, locking_number

    for name in ("light", "mid", "heavy"):
        p = example_params(name)
        assert locking_number(p, DEFAULT_FINEST_SPACING_M) < LOCKING_NUMBER_MAX
        assert finest_spacing_m(p) == DEFAULT_FINEST_SPACING_M
    mid = example_params("mid")
    pi = locking_number(mid, 0.005)
    assert locking_number(mid, 0.0025) == pytest.approx(pi / 4)  # h²
    bend = ("bend_k1_warp", "bend_k1_weft", "bend_k1_bias")
    # same bending length (k1/ρ), ρ / 13: Π × 13 through ρ g L c²
    light = dataclasses.replace(mid, density=mid.density / 13, **{k: getattr(mid, k) / 13 for k in bend})
    assert locking_number(light, 0.005) == pytest.approx(13 * pi, rel=1e-5)
    assert locking_number(light, 0.005) > LOCKING_NUMBER_MAX
    h = finest_spacing_m(light)
    assert h < DEFAULT_FINEST_SPACING_M
    assert locking_number(light, h) <= LOCKING_NUMBER_MAX < locking_number(light, h + 1e-4)  # rounded down to 0.1 mm
    stiffer_membrane = dataclasses.replace(light, stretch_alpha_warp=light.stretch_alpha_warp * 4,
                                           stretch_alpha_weft=light.stretch_alpha_weft * 4)
    assert finest_spacing_m(stiffer_membrane) < h
    lighter = dataclasses.replace(light, density=light.density / 2, **{k: getattr(light, k) / 2 for k in bend})
    assert finest_spacing_m(lighter) < h
    for bad in (dict(density=float("nan")), dict(density=0.0), dict(bend_k1_warp=-1e-6),
                dict(stretch_alpha_warp=float("nan"))):
        assert finest_spacing_m(dataclasses.replace(light, **bad)) == DEFAULT_FINEST_SPACING_M


@pytest.mark.parametrize("warp_deg", [0.0, 30.0])
def test_shape_operator_is_exact_on_quadratic_surfaces_of_an_unstructured_mesh(warp_deg):
    """Every triangle with three neighbours recovers the curvature tensor of a quadratic surface
    (small slope) in material axes from its hinge angles, on an unstructured mesh at any warp angle."""
    from drapejax.energy.shape_operator import hinge_angles, hinge_operator

    m = cusick_mesh(0.01, warp_angle_deg=warp_deg)
    st, rows, _, has, _ = hinge_operator(np.asarray(m.faces), np.asarray(m.uv), np.zeros(m.n_verts, bool))
    uv = np.asarray(m.uv)
    k_true = np.array([3.0, 1.0, -2.0])
    x = np.asarray(m.rest).copy()
    x[:, 2] = 0.5e-4 * (k_true[0] * uv[:, 0] ** 2 + 2 * k_true[1] * uv[:, 0] * uv[:, 1] + k_true[2] * uv[:, 1] ** 2)
    theta = np.asarray(jax.vmap(hinge_angles)(jnp.asarray(x)[st], jnp.asarray(has)))
    full = has.all(1)
    k = np.linalg.solve(rows[full], theta[full][..., None])[..., 0] / 1e-4
    assert full.sum() > 500
    np.testing.assert_allclose(k, np.broadcast_to(k_true, k.shape), atol=1e-4 * np.abs(k_true).max())


@pytest.mark.experiment
def test_shape_operator_cantilever_converges_to_the_master_curve():
    """Hinge shape-operator bending with its curvature-jump control droops within 3 % of the
    heavy-elastica master curve at 5 mm and within 1 % at 2.5 mm (Γ = 10, cut at 90°: the weft, the
    softer direction), closer on the finer mesh; without the jump control a strip droops 4-6 % too
    far (``energy.shape_operator.CurvatureJumpControl``)."""
    from drapejax.energy import Clamp, CurvatureJumpControl, Gravity, ShapeOperatorBending
    from drapejax.validate import cantilever_case

    terms = (Membrane(), ShapeOperatorBending(), CurvatureJumpControl(), Gravity(), Clamp())
    bare = (Membrane(), ShapeOperatorBending(), Gravity(), Clamp())
    coarse, fine = (cantilever_case(10.0, 90.0, sp, terms=terms) for sp in (0.005, 0.0025))
    assert coarse["converged"] and fine["converged"]
    assert fine["rel_err"] < coarse["rel_err"] < 0.03 and fine["rel_err"] < 0.01
    unstable = cantilever_case(10.0, 0.0, 0.0025, terms=bare)
    assert unstable["hw_sim"] > 1.03 * unstable["hw_ref"]


def test_curvature_jump_control_vanishes_on_quadratic_surfaces_and_charges_alternation():
    """The jump of the hinge curvature between triangles sharing an edge is zero for every quadratic
    surface (so the control adds no stiffness to uniform bending) and positive for a pattern that
    lifts alternate vertices."""
    from drapejax.energy import CurvatureJumpControl
    from drapejax.mesh import build_mesh

    base = cusick_mesh(0.01, warp_angle_deg=30.0)
    m = build_mesh(np.asarray(base.rest)[:, :2], np.asarray(base.faces), np.zeros(base.n_verts, bool), base.info)
    uv, p, term = np.asarray(m.uv), example_params("mid"), CurvatureJumpControl()
    x = np.asarray(m.rest).copy()
    x[:, 2] = 0.5e-4 * (3.0 * uv[:, 0] ** 2 + 2.0 * uv[:, 0] * uv[:, 1] - 2.0 * uv[:, 1] ** 2)
    idx, data = term.elements(m)
    per_pair = jax.vmap(term.element_energy, in_axes=(0, 0, None))(jnp.asarray(x)[idx], data, p)
    has = np.asarray(m.tri_has_edge).all(1)
    inner = has[np.asarray(m.tri_pairs)].all(1)
    bending = float(ShapeOperatorBending()(jnp.asarray(x), m, p))
    assert inner.sum() > 1000 and float(jnp.max(per_pair[inner])) < 1e-12 * bending
    y = np.asarray(m.rest).copy()
    y[:, 2] = 1e-4 * (np.arange(m.n_verts) % 2)
    assert float(term(jnp.asarray(y), m, p)) > 0.1 * float(ShapeOperatorBending()(jnp.asarray(y), m, p))


def test_a_drop_whose_steps_never_converge_cannot_gain_energy():
    """Implicit Euler with one Newton iteration per step (no step converges) on a heavy, soft,
    strongly stiffening fabric (a draw of the prior: 516 g/m², bending length 10 mm, β 11-14):
    each step starts where its incremental potential is lower, the current position or the
    inertial prediction, so the potential energy stays below the total energy of the step
    before. Starting from the prediction alone, such steps fling the hem half a metre up with
    an energy that overflows."""
    p = FabricParams.make(density=0.5163, bend_k1_warp=3.417e-6, bend_k1_weft=4.239e-6, bend_k1_bias=7.568e-6,
                          bend_k2_warp=-9.244e-9, bend_k2_weft=-6.516e-9, bend_k2_bias=-1.514e-8,
                          stretch_alpha_warp=470.8, stretch_alpha_weft=493.8, stretch_alpha_bias=137.0,
                          stretch_beta_warp=14.31, stretch_beta_weft=11.16, stretch_beta_bias=12.97)
    mesh = cusick_mesh(0.02, rim_spacing_m=0.003)
    cfg = SolverConfig(newton=NewtonConfig(max_iters=1, step_tol_m=1e-6), max_steps=100)
    r = drape(mesh, p, 0, terms=default_energies("cusick", buckling=True), config=cfg)
    assert np.isfinite(float(r.energy_j)) and float(r.energy_j) < 0.0
    assert float(jnp.max(r.x[:, 2])) < 1e-3
    assert int(r.status) == AT_REST


def test_the_softest_of_the_prior_come_to_rest():
    """The 10 softest of 200 prior fabrics (the softest 5 %, bending length (k1/ρg)^(1/3) of
    8.0-10.4 mm) all come to rest, hanging over the disc edge, in one batch on a small mesh."""
    from drapejax.inverse.prior import default_prior
    from drapejax.material import bending_length

    p = default_prior().sample(200, 0)
    soft = np.argsort(np.asarray(bending_length(p, "mean")))[:10]
    batch = FabricParams(**{k: getattr(p, k)[soft] for k in PARAM_KEYS})
    mesh = cusick_mesh(0.02)
    r = drape_batch(mesh, batch, jnp.arange(10), config=SolverConfig())
    assert np.asarray(r.status).tolist() == [AT_REST] * 10
    hem = np.linalg.norm(np.asarray(mesh.rest)[:, :2], axis=1) > 0.149
    assert np.all(np.asarray(r.x)[:, hem, 2].mean(1) < -0.015)
