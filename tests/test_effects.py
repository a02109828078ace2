"""Candidate effects: neutral at θ0, active and differentiable away from it, solver untouched."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.effects import REGISTRY, candidate_effects
from drapejax.energy import AbstractEnergy, default_energies, total_energy
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.solve import drape, quick_config


@pytest.fixture(scope="module")
def mesh():
    return cusick_mesh(0.03)


@pytest.fixture(scope="module")
def folded(mesh):
    """A smooth six-fold drape-like state: overhang hanging down with a wavy rim."""
    rest = np.asarray(mesh.rest)
    r = np.hypot(rest[:, 0], rest[:, 1])
    psi = np.arctan2(rest[:, 1], rest[:, 0])
    over = np.clip(r - 0.09, 0.0, None)
    z = -0.8 * over * (1.0 + 0.3 * np.cos(6 * psi))
    shrink = 1.0 - 0.4 * over / 0.06
    return jnp.asarray(np.stack([rest[:, 0] * shrink, rest[:, 1] * shrink, z], 1))


def _active_theta(effect):
    return np.asarray(effect.theta0(), float) + np.asarray(effect.prior_std(), float)


@pytest.mark.parametrize("effect", candidate_effects(), ids=lambda e: e.name)
def test_effect_is_neutral_at_theta0_and_active_elsewhere(mesh, folded, effect):
    p = example_params("mid")
    base = total_energy(default_energies("cusick"), folded, mesh, p)
    energy = lambda th, x: total_energy(effect.terms(mesh, th), x, mesh, p)
    th0 = jnp.asarray(effect.theta0(), float)
    assert float(energy(th0, folded)) == pytest.approx(0.0, abs=1e-12 * abs(float(base)))
    np.testing.assert_allclose(jax.grad(energy, argnums=1)(th0, folded), 0.0, atol=1e-12)
    th = jnp.asarray(_active_theta(effect))
    x = folded
    if effect.name == "self_contact":  # bring two fold walls within the thickness (1 mm apart)
        i, j = np.asarray(effect.terms(mesh, th)[0].pairs[0])
        x = folded.at[j].set(folded[i] + jnp.array([1e-3, 0.0, 0.0]))
    e1 = float(energy(th, x))
    g_x = np.asarray(jax.grad(energy, argnums=1)(th, x))
    g_th = np.asarray(jax.grad(energy)(th, x))
    assert e1 != 0.0 and np.all(np.isfinite(g_x)) and np.abs(g_x).max() > 0
    assert np.all(np.isfinite(g_th)) and np.abs(g_th).max() > 0
    # θ-gradient agrees with central differences (the refits differentiate through it)
    i = int(np.argmax(np.abs(g_th)))
    h = 1e-6 * max(1.0, abs(float(th[i])))
    fd = (float(energy(th.at[i].add(h), x)) - float(energy(th.at[i].add(-h), x))) / (2 * h)
    assert g_th[i] == pytest.approx(fd, rel=1e-4)


def test_off_centre_drape_moves_the_skirt_and_keeps_the_solver(mesh):
    """A 15 mm shift lengthens the overhang on one side: the rim's centroid moves against it."""
    p = example_params("mid")
    eff = REGISTRY["off_centre"]
    terms = default_energies("cusick") + eff.terms(mesh, jnp.array([0.015, 0.0]))
    res = jax.jit(lambda: drape(mesh, p, 0, terms=terms, config=quick_config()))()
    assert int(res.status) in (0, 1)  # the clamp ramps are only piecewise smooth: Newton may stall near rest
    x = np.asarray(res.x)
    assert np.all(np.isfinite(x))
    rest = np.asarray(mesh.rest)
    rim = np.hypot(rest[:, 0], rest[:, 1]) > 0.145
    # specimen centre at +15 mm: the overhang is longer on +x, shorter on −x
    assert np.mean(x[rim, 0]) > 0.005
    clamped = np.asarray(mesh.clamped)
    centre = np.argmin(np.hypot(rest[:, 0], rest[:, 1]))
    assert clamped[centre] and x[centre, 0] == pytest.approx(0.015, abs=1e-3)


@pytest.mark.parametrize("effect", candidate_effects(), ids=lambda e: e.name)
def test_probes_are_distinct_one_axis_moves_within_bounds(effect):
    from drapejax.diagnose import Screen

    t0, sd, lo = effect.theta0(), effect.prior_std(), effect.lower_bound()
    scr = Screen()
    ps = effect.probes(scr.steps, scr.vector_steps)
    assert ps and len({tuple(p) for p in ps}) == len(ps)
    for p in ps:
        moved = np.flatnonzero(p != t0)
        assert len(moved) == 1 and np.all(p >= lo)
        i = moved[0]
        steps = scr.steps if len(t0) == 1 else scr.vector_steps
        assert p[i] == lo[i] or any(np.isclose(p[i], t0[i] + k * sd[i]) for k in steps)


def test_closed_form_element_hessians_equal_autodiff(mesh, folded):
    """Where a term gives its ``element_hessian`` in closed form (the matrix of exact Newton
    steps and of the implicit adjoint), it equals the autodiff Hessian of its ``element_energy``:
    base terms' and every candidate effect's, on a rough state (so that the hourglass residuals
    and the bending's nonlinear part are all active)."""
    p = example_params("mid")
    rough = folded + 1e-3 * jax.random.normal(jax.random.PRNGKey(1), folded.shape, folded.dtype)
    terms = list(default_energies("cusick"))
    for effect in candidate_effects():
        terms += effect.terms(mesh, jnp.asarray(_active_theta(effect)))
    closed = [t for t in terms if type(t).element_hessian is not AbstractEnergy.element_hessian]
    assert {"Bending", "HourglassControl", "EdgeCurlTerm", "ClampHingeTerm", "ClampHingeHourglass"} <= {
        type(t).__name__ for t in closed}
    for term in closed:
        idx, data = term.elements(mesh)
        got = jax.jit(jax.vmap(lambda xe, d: term.element_hessian(xe, d, p)))(rough[idx], data)
        auto = jax.jit(jax.vmap(lambda xe, d: AbstractEnergy.element_hessian(term, xe, d, p)))(rough[idx], data)
        scale = float(jnp.max(jnp.abs(auto)))
        assert scale > 0.0, type(term).__name__
        np.testing.assert_allclose(got, auto, rtol=0, atol=1e-11 * scale, err_msg=type(term).__name__)


@pytest.mark.parametrize("name", ["bending_saturation", "clamp_hinge"])
def test_softening_effects_soften_newtons_hessian_and_keep_it_psd(mesh, folded, name):
    """An effect that removes bending energy must show up in the Hessian Newton steps use, which
    must stay PSD: projecting each term on its own drops the negative one, and Newton then sees
    the unsoftened fabric."""
    from drapejax.solve._sparse import hessian_coo

    p, effect = example_params("mid"), REGISTRY[name]
    base = default_energies("cusick")
    zero = jnp.zeros(mesh.n_verts)

    def dense(terms):
        rows, cols, vals = hessian_coo(terms, folded, mesh, p, zero, project=True)
        return np.asarray(jnp.zeros((3 * mesh.n_verts,) * 2).at[rows, cols].add(vals))

    h0 = dense(base)
    h1 = dense(base + effect.terms(mesh, jnp.asarray([2.0])))
    w = np.linalg.eigvalsh(0.5 * (h1 + h1.T))
    assert w.min() > -1e-9 * w.max()
    soften = np.linalg.eigvalsh(0.5 * ((h1 - h0) + (h1 - h0).T))  # negative semi-definite, and not zero
    assert soften.max() < 1e-9 * w.max() and soften.min() < -1e-6 * w.max()


def test_saturation_keeps_the_bending_energy_convex_for_any_theta():
    """Bending + saturation stays convex in the curvature tensor at large θ (the removed
    fraction stays below 0.7), so no θ a fit reaches makes the example fabrics kink."""
    from drapejax.effects.bending_saturation import BendingSaturationTerm
    from drapejax.energy.bending import bending_density

    rng = np.random.default_rng(0)
    v = rng.normal(size=(40, 500, 3))
    v = np.geomspace(5.0, 500.0, 40)[:, None, None] * v / np.linalg.norm(v, axis=-1, keepdims=True)
    v = jnp.asarray(v.reshape(-1, 3))  # (K11, K22, K12), 1/m
    for fabric in ("light", "mid", "heavy"):
        p = example_params(fabric)
        for theta in (1.0, 10.0):
            term = BendingSaturationTerm(theta=jnp.asarray(theta))

            def w(k):
                big_k = jnp.array([[k[0], k[2]], [k[2], k[1]]])
                return bending_density(big_k, p) + term.density(big_k, None, p)

            eig = np.linalg.eigvalsh(np.asarray(jax.vmap(jax.hessian(w))(v)))
            assert (eig[:, 0] / eig[:, -1]).min() > 0.0, (fabric, theta)


def test_heterogeneity_orders_nest(mesh, folded):
    """The candidate field takes harmonics 1 and 2 (cos ψ, sin ψ, cos 2ψ, sin 2ψ of the material
    polar angle); with the second harmonic at zero it is the one-harmonic field (a rigidity
    gradient across the specimen) exactly, and a second harmonic changes it."""
    from drapejax.effects import Heterogeneity

    p = example_params("mid")
    one, two = Heterogeneity(harmonics=1), Heterogeneity()
    assert one.n_params() == 2 and two.n_params() == 4 and REGISTRY["heterogeneity"] == two
    energy = lambda eff, th: float(total_energy(eff.terms(mesh, jnp.asarray(th)), folded, mesh, p))
    assert energy(two, [0.4, -0.3, 0.0, 0.0]) == pytest.approx(energy(one, [0.4, -0.3]), rel=1e-12)
    assert energy(two, [0.4, -0.3, 0.2, 0.0]) != pytest.approx(energy(one, [0.4, -0.3]), rel=1e-6)
    uv = np.asarray(mesh.uv[mesh.curv_verts])
    psi = np.arctan2(uv[:, 1], uv[:, 0])
    basis = np.asarray(two.terms(mesh, jnp.zeros(4))[0].vertex_data(mesh))
    np.testing.assert_allclose(basis, np.stack([np.cos(psi), np.sin(psi), np.cos(2 * psi), np.sin(2 * psi)], 1),
                               atol=1e-12)
    assert two.describe([0.3, 0.4, 0.0, 0.5]) == pytest.approx({"log_rigidity_harmonic1": 0.5,
                                                                 "log_rigidity_harmonic2": 0.5})
    with pytest.raises(ValueError, match="harmonics"):
        Heterogeneity(harmonics=0)


def test_bending_friction_adds_a_constant_moment_to_any_cylindrical_bend():
    """Grosberg's loading branch M = M0 + B κ: the friction term's moment along a cylindrical bend of
    any direction is M0 (θ times the geometric-mean k1) beyond the smoothing curvature, and its
    energy density is convex in the curvature tensor."""
    from types import SimpleNamespace

    from drapejax.effects.bending_friction import BendingFrictionTerm, friction_moment
    from drapejax.diagnose.signatures import Evidence

    p = example_params("mid")
    term = BendingFrictionTerm(theta=jnp.asarray(20.0))
    m0 = float(friction_moment(20.0, p))
    assert m0 == pytest.approx(20.0 * (13.8e-6 * 8.8e-6 * 11.5e-6) ** (1 / 3), rel=1e-12)
    for phi in np.radians([0.0, 30.0, 45.0, 90.0]):
        n = jnp.array([np.cos(phi), np.sin(phi)])
        moment = jax.grad(lambda k: term.density(k * jnp.outer(n, n), None, p))
        for kappa in (15.0, 50.0, 200.0):
            assert float(moment(kappa)) == pytest.approx(m0, rel=1e-2)
        assert float(moment(0.0)) == 0.0 and 0.0 < float(moment(1.0)) < 0.5 * m0

    def w(k):
        return term.density(jnp.array([[k[0], k[2]], [k[2], k[1]]]), None, p)

    v = jnp.asarray(np.random.default_rng(0).normal(scale=30.0, size=(200, 3)))
    assert np.linalg.eigvalsh(np.asarray(jax.vmap(jax.hessian(w))(v))).min() > -1e-12 * m0

    # its signature: folds the measured rim has beyond the fitted one's
    phi = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    rims = {k: 0.12 + 0.01 * np.cos(k * phi) for k in (6, 7, 8)}
    friction = REGISTRY["bending_friction"]
    score = lambda meas, sim: friction.signature(Evidence(SimpleNamespace(rim_measured=rims[meas],
                                                                           rim_simulated=rims[sim])))
    assert score(8, 6) == 1.0 and score(7, 6) == 0.5 and score(6, 6) == 0.0 and score(6, 8) == 0.0


@pytest.mark.experiment
def test_bending_friction_stiffens_the_drape(mesh):
    """A frictional moment resists every bend: the same fabric drapes with a higher drape
    coefficient, and more so the larger the moment."""
    from drapejax import observe

    p = example_params("mid")
    eff = REGISTRY["bending_friction"]
    run = jax.jit(lambda th: drape(mesh, p, 0, terms=default_energies("cusick") + eff.terms(mesh, th),
                                   config=quick_config()))
    dc = []
    for theta in (0.0, 20.0, 40.0):
        res = run(jnp.array([theta]))
        assert int(res.status) == 0
        sil = observe.silhouette(np.asarray(res.x), np.asarray(mesh.faces), n=256, extent_m=0.16)
        dc.append(float(observe.drape_coefficient(sil, 0.16, specimen_radius_m=mesh.info.specimen_radius_m,
                                                  disk_radius_m=mesh.info.disk_radius_m)))
    assert dc[0] + 0.01 < dc[1] < dc[2] - 0.01, dc
