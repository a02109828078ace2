"""Refinement through the simulator: synthetic recovery, never-worse, NaN path, uncertainty."""

import numpy as np
import pytest

import jax
import jax.numpy as jnp

from drapejax import observe, refine
from drapejax.io import load_measurement, write_measurement
from drapejax.material import example_params, from_log_theta
from drapejax.mesh import cusick_mesh
from drapejax.solve import drape, quick_config

from helpers import QuadraticProblem

SPACING_M = 0.025
SCALE_TRUE = 2.0


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A simulated measurement (seed 7) of the "mid" fabric with all k1 ×2, and a Problem started at "mid"."""
    mesh = cusick_mesh(SPACING_M)
    p0 = example_params("mid")
    truth = from_log_theta(p0, jnp.full(3, np.log(SCALE_TRUE)))
    x = np.asarray(jax.jit(lambda p: drape(mesh, p, 7, config=quick_config()))(truth).x)
    faces = np.asarray(mesh.faces)
    folder = tmp_path_factory.mktemp("refine") / "m"
    write_measurement(folder, test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                      areal_density_kg_m2=float(p0.density), warp_angle_deg=0.0,
                      silhouette=observe.silhouette(x, faces, n=256, extent_m=0.16),
                      height=observe.height_map(x, faces, n=256, extent_m=0.16), scan=(x, faces))
    m = load_measurement(folder)
    prob = refine.Problem(mesh, refine.measured_targets(m), p0, (), np.zeros(3), np.array([np.log(3.0), 0.25]),
                          SPACING_M)
    return m, prob


def test_refinement_recovers_overall_stiffness_and_never_ends_worse(synthetic):
    _, prob = synthetic
    res = refine.run_lm(prob, np.zeros(3), max_steps=6, seed=0)
    assert res.loss <= res.loss_start
    # The fit explains the data at least as well as the true parameters do, with the true rest
    # state reached from the fitted one (same fold pattern: the rest of the misfit is the
    # fold placement of a different drop, not the material).
    x_true = prob.rest(np.full(3, np.log(SCALE_TRUE)), 0)
    r_true, _ = prob.evaluate(np.full(3, np.log(SCALE_TRUE)), x_true, jacobian=False)
    assert res.loss <= 0.5 * float(r_true @ r_true) < res.loss_start
    # A different drop seed: individual directions are weakly identified at 25 mm, the geometric
    # mean of the three k1 (what the DC measures) is recovered within 30%.
    gm = float(np.exp(np.mean(res.theta)))
    assert abs(np.log(gm / SCALE_TRUE)) < np.log(1.3), (gm, res.theta)
    sd = np.sqrt(np.diag(res.cov))
    assert np.all(np.isfinite(sd)) and np.all(sd > 0)
    prior_sd = np.sqrt(np.diag(np.linalg.inv(prob.prior_sqrt_info.T @ prob.prior_sqrt_info)))
    assert np.all(sd <= prior_sd + 1e-9)  # data can only shrink the prior spread
    ident = refine.identified(res.cov)
    assert np.all((ident["data_share"] >= 0) & (ident["data_share"] <= 1))
    assert np.sum(np.abs(ident["weights"])) == pytest.approx(1.0) and 0 < ident["std_log"] < np.inf
    # a model reached without a fit (a scan's drop) gets the covariance the fit would report there,
    # and a fit's own is that matrix (``select.fabric_estimate`` uses it rather than evaluating it again)
    assert res.status in refine.LAPLACE_STATUSES
    np.testing.assert_allclose(refine.laplace_cov(prob, res.theta, res.x), res.cov, rtol=1e-6)
    params, std = refine.reported_params(res.params, False, sd[:3])
    assert "density" not in params and params["bend_k1_warp_per_density"] == pytest.approx(
        float(res.params.bend_k1_warp) / float(res.params.density))
    assert std["bend_k1_bias_per_density"] == pytest.approx(params["bend_k1_bias_per_density"] * sd[2])
    assert std["stretch_alpha_warp_per_density"] is None


def test_identified_separates_what_the_drape_saw_from_the_prior():
    """A drape that informs only the bias k1: ``identified`` returns that direction with its
    data-only std, and reports warp and weft as restating the prior."""
    jd = np.array([[0.0, 0.0, 20.0], [0.0, 0.0, 10.0]])
    lp = refine.prior_sqrt_information(np.array(refine.K_PRIOR_STD), 3)
    out = refine.identified(np.linalg.inv(jd.T @ jd + lp.T @ lp))
    np.testing.assert_allclose(out["weights"], [0.0, 0.0, 1.0], atol=1e-9)
    assert out["std_log"] == pytest.approx(1.0 / np.sqrt(500.0))
    p_bias = (lp.T @ lp)[2, 2]
    np.testing.assert_allclose(out["data_share"], [0.0, 0.0, 500.0 / (500.0 + p_bias)], atol=1e-9)
    with pytest.raises(refine.RefineError, match="3x3"):
        refine.identified(np.eye(4))


def test_nan_residual_returns_start(synthetic):
    _, prob = synthetic

    class NanProblem(refine.Problem):
        def hard(self, x):
            return np.full(super().hard(x).shape, np.nan)

    bad = object.__new__(NanProblem)
    bad.__dict__.update(prob.__dict__)
    bad.x = None
    res = refine.run_lm(bad, np.zeros(3), max_steps=3)
    assert res.status == "nan_returned_start"
    np.testing.assert_array_equal(res.theta, np.zeros(3))


def test_failed_steps_return_start(synthetic):
    _, prob = synthetic

    class DivergingProblem(refine.Problem):
        calls = 0

        def rest(self, theta, seed):
            self.calls += 1
            x = super().rest(theta, seed)
            return x if self.calls == 1 else np.full_like(x, np.nan)

    bad = object.__new__(DivergingProblem)
    bad.__dict__.update(prob.__dict__)
    bad.x = None
    res = refine.run_lm(bad, np.zeros(3), max_steps=8)
    assert res.status == "no_improvement_returned_start"
    assert res.loss == res.loss_start
    np.testing.assert_array_equal(res.theta, np.zeros(3))


def test_impossible_parameters_have_no_rest_state(synthetic):
    """A bias k1 148x the fit's (no positive-definite plate has it): the drape would return its
    safe stand-in material's rest state, so the problem returns NaN (a fit step is rejected, a
    screened drop skipped) instead of scoring that state as this θ's."""
    from drapejax.material import validity

    _, prob = synthetic
    bad = np.array([0.0, 0.0, 5.0])
    assert not bool(validity(from_log_theta(prob.init, jnp.asarray(bad))))
    assert np.all(np.isnan(prob.drop(bad, 0)))
    prob.x = np.asarray(prob.mesh.rest)
    assert np.all(np.isnan(prob.rest(bad, 0)))  # the warm-started static solve too
    prob.x = None


def test_problems_of_different_fabrics_share_one_compiled_program(synthetic):
    """The starting fabric is an argument of a problem's programs, not a constant of them: the fit
    of another capture (another network start) runs the drop, static solve and soft features
    already compiled, in the process and from the persistent cache, instead of compiling them
    again; each problem still solves its own fabric."""
    _, prob = synthetic
    heavy = example_params("heavy")
    other = refine.Problem(prob.mesh, prob.targets, heavy, (), np.zeros(3), np.array([np.log(3.0), 0.25]), SPACING_M)
    for name in ("_drape", "_static", "_soft", "_soft_jac"):
        assert getattr(other, name).func is getattr(prob, name).func, name
    th = jnp.zeros(3)
    text = lambda pr: pr._drape.func.lower(*pr._drape.args, th, 0).as_text()
    assert text(other) == text(prob)
    assert float(other.split(th)[0].density) == pytest.approx(float(heavy.density))
    assert float(prob.split(th)[0].density) == pytest.approx(float(prob.init.density))
    assert float(heavy.density) != pytest.approx(float(prob.init.density))


def test_programs_compiled_ahead_are_not_compiled_again_by_the_first_drop(synthetic):
    """``prepare_programs`` compiles (or loads from the persistent cache) a problem's drop program
    before its first drop, which then runs it as it is: no compilation and no cache load happen
    in the drop. A fresh effect callable gives the problem a program of its own."""
    from jax import monitoring

    _, prob = synthetic
    fresh = refine.Problem(prob.mesh, prob.targets, prob.init, (lambda mesh, th: (),), np.zeros(3),
                           np.array([np.log(3.0), 0.25]), SPACING_M)
    work: list[str] = []

    def listen(name, seconds, **_):
        if ("backend_compile" in name and seconds > 1.0) or "cache_retrieval" in name:
            work.append(name)

    monitoring.register_event_duration_secs_listener(listen)
    try:
        refine.prepare_programs(fresh.programs(solves=False), threads=2)
        assert work, "the drop program was neither compiled nor loaded ahead"
        work.clear()
        x = fresh.drop(np.zeros(3), np.int64(3))  # a numpy seed runs the same program
        assert work == []
    finally:
        monitoring.unregister_event_duration_listener(listen)
    assert np.all(np.isfinite(x))


@pytest.mark.experiment
def test_refit_with_a_null_effect_continues_its_start(synthetic):
    """A refit that adds an effect at null, continued from an earlier fit, starts at exactly that
    fit's loss (same rest state, so the same fold pattern) and can only lower it: effect
    selection compares nested models, not two drops."""
    from drapejax.diagnose.select import combine
    from drapejax.effects import HeavyHem

    m, prob = synthetic
    base = refine.fit(m, init=prob.init, spacing_m=SPACING_M, mesh=prob.mesh, max_steps=2, seed=0)
    hem = HeavyHem()
    res = refine.fit(m, init=prob.init, spacing_m=SPACING_M, mesh=prob.mesh, effects=[combine([hem])],
                     theta_effects0=hem.theta0(), prior_std=np.r_[refine.K_PRIOR_STD, hem.prior_std()], max_steps=2,
                     start=base)
    assert res.history[0] == pytest.approx(base.loss, rel=1e-6)
    assert res.loss <= base.loss
    with pytest.raises(refine.RefineError, match="start has 4 parameters"):
        refine.fit(m, init=prob.init, spacing_m=SPACING_M, mesh=prob.mesh, start=res)


def test_an_effect_held_away_from_null_is_solved_before_the_k1_refit(synthetic):
    """Holding an effect the start did not have at a value away from its null (a bench reading's
    finding) changes the rest state: the refit solves it first, warm-started from the start's, so its
    first loss is that drape's, not the start's, and the state it returns carries the effect."""
    from drapejax.diagnose.trials import held_refit
    from drapejax.effects import HeavyHem

    m, prob = synthetic
    base = refine.fit(m, init=prob.init, spacing_m=SPACING_M, mesh=prob.mesh, max_steps=0, seed=0)
    hem = HeavyHem()
    theta = np.asarray(hem.theta0(), float) + 3.0 * np.asarray(hem.prior_std(), float)
    res = held_refit(m, base, [hem], theta, init=prob.init, mesh=prob.mesh, spacing_m=SPACING_M, max_steps=0)
    np.testing.assert_allclose(res.theta[3:], theta, rtol=1e-9)
    assert abs(res.history[0] - base.loss) > 1e-3 * base.loss
    assert np.max(np.abs(np.asarray(res.x) - np.asarray(base.x))) > 1e-4
    same = held_refit(m, base, [], np.zeros(0), init=prob.init, mesh=prob.mesh, spacing_m=SPACING_M, max_steps=0)
    assert same.history[0] == pytest.approx(base.loss, rel=1e-6)  # nothing moved: the start is scored as it is


def test_steps_stay_above_the_lower_bounds():
    """A parameter whose best value lies below its physical limit (a hem's extra density below
    -1, i.e. negative mass) ends at the limit, while the free ones reach their optimum."""

    res = refine.run_lm(QuadraticProblem(), np.zeros(4), max_steps=20)
    assert res.theta[3] == -1.0
    np.testing.assert_allclose(res.theta[:3], QuadraticProblem.target[:3], atol=1e-3)
    assert res.loss == pytest.approx(0.5 * 2.0**2, abs=1e-5)


def test_bending_length_depends_on_k_over_rho_and_flags_soft_fabrics():
    """(k̄1/ρg)^(1/3): ×8 rigidity doubles it, scaling k and ρ together leaves it; soft fabrics get a mesh warning."""
    from drapejax.material import FabricParams

    def scaled(p, k=1.0, rho=1.0):
        d = p.to_dict()
        for key in d:
            if key.startswith("bend_k"):
                d[key] *= k * rho
        d["density"] *= rho
        return FabricParams.from_dict(d)

    mid = example_params("mid")
    lb = refine.bending_length_m(mid)
    k1 = (float(mid.bend_k1_warp) * float(mid.bend_k1_weft) * float(mid.bend_k1_bias)) ** (1 / 3)
    assert lb == pytest.approx((k1 / (float(mid.density) * 9.81)) ** (1 / 3), rel=1e-3)
    assert refine.bending_length_m(scaled(mid, k=8.0)) == pytest.approx(2 * lb, rel=1e-9)
    assert refine.bending_length_m(scaled(mid, rho=3.0)) == pytest.approx(lb, rel=1e-9)
    assert refine.mesh_warnings(mid, 0.02) == [] and refine.mesh_warnings(example_params("heavy"), 0.02) == []
    light = example_params("light")
    assert refine.bending_length_m(light) < refine.MIN_BENDING_LENGTH_M
    assert "bending length" in refine.mesh_warnings(light, 0.02)[0] and refine.mesh_warnings(light, 0.005) == []
    assert refine.mesh_warnings(light, 0.02, buckling=True) == []
    assert "not checked" in refine.mesh_warnings(scaled(light, k=0.5), 0.02, buckling=True)[0]


def test_profile_rows_replace_the_fitted_rings_and_score_a_lower_skirt(synthetic):
    """Selection's misfit (``profile=True``) scores the skirt's height profile and its world-frame
    first harmonic in place of the fit's two rings: zero on the measured drape itself, and a drape
    hanging 4 mm lower costs ½ Σ (4 mm / σ_ring)² there (its first harmonic unchanged), against
    ½ Σ (4 mm / 5 mm)² on the fit's rows. It has no Jacobian."""
    m, prob = synthetic
    x = np.asarray(m.scan_vertices, float)
    fit_rows, sel_rows = refine.Misfit(prob.mesh, prob.targets), refine.Misfit(prob.mesh, prob.targets, profile=True)
    assert sel_rows.n_rows == fit_rows.n_rows - len(refine.RING_RADII_M) + len(refine.PROFILE_RADII_M) + 2
    assert sel_rows.loss(x) == pytest.approx(0.0, abs=1e-9)
    lower = x - np.array([0.0, 0.0, 0.004])
    rings = 0.5 * np.sum((0.004 / np.asarray(refine.SIGMA_PROFILE_M)) ** 2)
    assert sel_rows.loss(lower) == pytest.approx(rings + 0.5 * (0.004 / refine.SIGMA_HEM_M) ** 2, rel=0.1)
    assert fit_rows.loss(lower) == pytest.approx(1.5 * (0.004 / refine.SIGMA_HEM_M) ** 2, rel=0.1)
    sel_prob = refine.Problem(prob.mesh, prob.targets, prob.init, (), np.zeros(3), np.array([np.log(3.0), 0.25]),
                              SPACING_M, profile=True)
    with pytest.raises(refine.RefineError, match="Jacobian"):
        sel_prob.evaluate(np.zeros(3), x, jacobian=True)


def test_targets_of_a_folder_with_only_a_point_cloud_or_only_a_photo(single_observation):
    """Refinement and diagnosis read any single observation the format allows: a point-cloud scan
    gives the scan mesh's drape coefficient and skirt heights, a photo (rendered from the real
    scan, tilted 8°) its drape coefficient (a photo has no heights)."""
    from drapejax.diagnose.residuals import measured_views

    m, cloud_folder, photo_folder = single_observation
    cloud, only_photo = load_measurement(cloud_folder), load_measurement(photo_folder)
    full, t_cloud, t_photo = (refine.measured_targets(x) for x in (m, cloud, only_photo))
    assert abs(t_cloud.dc - full.dc) < 0.005 and abs(t_photo.dc - full.dc) < 0.015
    assert abs(t_cloud.hem_m - full.hem_m) < 1e-3 and np.allclose(t_cloud.rings_m, full.rings_m, atol=1e-3)
    assert t_photo.hem_m is None and t_photo.rings_m is None
    for x in (cloud, only_photo):
        views = measured_views(x)
        assert observe.iou(views.silhouette, measured_views(m).silhouette) > 0.95


@pytest.mark.parametrize("test, half_or_radius", [("cusick", 0.15), ("square", 0.15), ("square", 0.12)])
def test_soft_drape_coefficient_of_a_flat_specimen_is_one(test, half_or_radius):
    """The fit's differentiable drape coefficient divides by the specimen's own area: a flat
    (undraped) circle or square of either size scores 1, to within the soft outline's smoothing
    (one mesh spacing), as the hard drape coefficient does exactly. (Over a circle's area, the
    30 cm square would score 1.48.)"""
    from drapejax.mesh import square_mesh

    mesh = (cusick_mesh(SPACING_M, radius_m=half_or_radius) if test == "cusick"
            else square_mesh(SPACING_M, half_side_m=half_or_radius))
    soft = np.asarray(refine._soft_features(mesh.rest, mesh, SPACING_M))
    assert abs(soft[refine._F["dc"]] - 1.0) < 0.08 and soft[refine._F["hem"]] == 0.0


@pytest.mark.experiment
def test_the_converged_refit_continues_the_coarse_fit_on_the_finer_model(tmp_path):
    """A capture made as ``drapejax simulate`` makes it (nested hierarchy, here one 20 mm level; drop
    seed 1) of "mid" with every k1 ×2, estimated on a uniform 30 mm fit mesh and then continued on
    the capture's 20 mm hierarchy (``estimate(..., converged_spacing_m=0.02)``). The refit starts
    at the coarse fit's parameters scored on the finer model, never ends above that loss, reports
    the finer mesh, and comes closer to the true overall rigidity than the coarse fit: a coarser
    mesh drapes lower at the same k1, so the coarse fit comes out stiffer than the fabric."""
    from drapejax.cli import simulate_to_folder

    truth = from_log_theta(example_params("mid"), jnp.full(3, np.log(SCALE_TRUE)))
    simulate_to_folder(truth, test="cusick", spacing_m=0.02, seed=1, out=tmp_path / "m")
    out = refine.estimate(tmp_path / "m", spacing_m=0.03, rim_spacing_m=None, max_steps=4, converged_spacing_m=0.02)
    c = out["converged"]
    assert c["status"] in refine.LAPLACE_STATUSES and c["loss"] <= c["loss_coarse_model"]
    assert out["spacing_m"] == 0.02 and [lv["spacing_m"] for lv in c["levels"]] == [0.02]
    assert c["drape_status"] == "at_rest"

    def overall(d):
        return float(np.exp(np.mean([np.log(d[f"bend_k1_{k}"]) for k in ("warp", "weft", "bias")])))

    true, coarse, fine = overall(truth.to_dict()), overall(c["params_coarse"]), overall(out["params"])
    assert coarse > true and abs(np.log(fine / true)) < abs(np.log(coarse / true)), (true, coarse, fine)


def test_height_first_harmonic_reads_a_skirt_lower_on_one_side_despite_missing_sectors():
    """A skirt whose height is z0 + a cos φ + b sin φ gives (a, b) back, on the world frame's axes,
    also with two whole sectors of an outer ring without fabric (fold troughs); a level skirt
    gives zero."""
    n, ext = 256, refine.EXTENT_M
    c = (np.arange(n) + 0.5) / n * 2 * ext - ext
    xx, yy = np.meshgrid(c, c[::-1])
    rho, phi = np.hypot(xx, yy), np.arctan2(yy, xx)
    skirt = (rho > 0.09) & (rho < 0.13)
    z = np.where(skirt, -0.04 - 0.008 * np.cos(phi) + 0.003 * np.sin(phi), np.nan)
    assert refine.height_first_harmonic(z, ext) == pytest.approx([-0.008, 0.003], abs=3e-4)
    trough = (rho > 0.112) & ((np.abs(phi - 0.3) < 0.2) | (np.abs(phi + 2.0) < 0.2))
    assert refine.height_first_harmonic(np.where(trough, np.nan, z), ext) == pytest.approx([-0.008, 0.003], abs=3e-4)
    assert refine.height_first_harmonic(np.where(skirt, -0.04, np.nan), ext) == pytest.approx([0.0, 0.0], abs=1e-9)
