"""Bench tests on strips as rows of the identifiability analysis (``diagnose.strip``).

The pure bending test reads Grosberg's (1966) loading branch M = M0 + Bκ off the model; a strip
feels an effect of the fabric (a frictional couple) and not one of the drape test's setup (a hem
band); an effect that is a change of k1 under another name shifts the pure bending rows exactly as
that change of k1 does, so they cannot tell them apart, while they do tell a frictional couple.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.diagnose.identifiability import strip_information, theta_stds
from drapejax.diagnose.strip import (KES_CURVATURES_PER_M, KES_UNLOADING_CURVATURES_PER_M, BenchResponse,
                                     PureBendingTest, StripTest)
from drapejax.effects import BendingFriction, BendingSaturation, BiasAsymmetry, Effect, HeavyHem
from drapejax.effects.bending_friction import friction_moment
from drapejax.energy import AbstractEnergy, Bending, HourglassControl
from drapejax.material import example_params
from drapejax.validate import linear_params


class _Scaled(AbstractEnergy):
    """``scale`` times another term's energy."""

    term: AbstractEnergy
    scale: jnp.ndarray

    def elements(self, mesh):
        return self.term.elements(mesh)

    def element_energy(self, xe, data, params):
        return self.scale * self.term.element_energy(xe, data, params)


class FabricRescale(Effect):
    """Every bending rigidity of the fabric times 1 + θ, on the drape and on a strip cut from it:
    a uniform change of k1 (and k2) under another name."""

    name: str = eqx.field(static=True, default="fabric_rescale")

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([0.3])

    def terms(self, mesh, theta):
        return tuple(_Scaled(term=t, scale=theta[0]) for t in (Bending(), HourglassControl()))

    def strip_terms(self, mesh, theta):
        return self.terms(mesh, theta)

    def describe(self, theta):
        return {"bending_scale": 1.0 + float(theta[0])}


@pytest.fixture(scope="module")
def fabric():
    return example_params("mid")


def test_pure_bending_reads_the_elastic_line_and_the_frictional_couple(fabric):
    """Linear fabric: the moment per unit width is k1 κ along each cut (within 3 %: the bias's
    anisotropic plate on this mesh); a frictional couple adds M0 = θ k̄1 at every curvature of the
    test (within 6 %: its curvature is the plain quadratic fit, which under-counts a bend of 0.34
    rad per spacing at 150 1/m by 5 %)."""
    p = linear_params(fabric)
    theta = 10.0
    for d in ("warp", "weft", "bias"):
        t = PureBendingTest(p, d)
        k1 = float(getattr(p, f"bend_k1_{d}"))
        for kappa in KES_CURVATURES_PER_M:
            m = math.exp(t.log_moment(kappa))
            assert abs(m / (k1 * kappa) - 1.0) < 0.03, (d, kappa, m / (k1 * kappa))
            mf = math.exp(t.log_moment(kappa, extra_terms=BendingFriction().strip_terms(t.mesh(), np.array([theta]))))
            m0 = float(friction_moment(theta, p))
            assert abs((mf - m) / m0 - 1.0) < 0.06, (d, kappa, (mf - m) / m0)


def test_strip_rows_feel_the_fabric_not_the_setup(fabric):
    """A heavier hem band is not on a strip: no shift and no solve. A frictional couple lifts the
    cantilever strip and stiffens every loading row of pure bending, the lower curvature's more (a
    constant moment's share falls with curvature), and softens the unloading rows as much; a
    rescale of the fabric's bending shifts every row as the same change of log k1 does (0.3 per
    prior std of 0.3). So the rows, with k1 free, cannot separate the rescale, and they do
    separate the friction."""
    p = linear_params(fabric)  # k2 = 0: a rescale of the bending is then one of k1 alone
    bench = BenchResponse(p)
    assert np.array_equal(bench.shift(HeavyHem(), "cantilever", "bias", 0.3), np.zeros((1, 1)))
    assert not bench._cache
    strip = StripTest(p, "bias")
    lifted = strip.log_droop(extra_terms=BendingFriction().strip_terms(strip.mesh(), np.array([10.0])))
    plain = strip.log_droop()
    assert lifted[1] and plain[1] and lifted[0] < plain[0] - 0.05, (lifted, plain)
    shifts = {e.name: bench.shift(e, "pure_bending", "bias", 0.3) for e in (FabricRescale(), BendingFriction())}
    assert np.allclose(shifts["fabric_rescale"], 0.3, rtol=0.02), shifts  # 45° plate: k1_bias is not all of it
    n = len(KES_CURVATURES_PER_M)
    rows, unloading = shifts["bending_friction"][:n, 0], shifts["bending_friction"][n:, 0]
    assert np.all(rows > 0) and np.all(rows[:-1] > 1.5 * rows[1:]), shifts
    # unloading, the couple resists the other way: the same rows, as large, the other sign
    loaded = rows[[KES_CURVATURES_PER_M.index(k) for k in KES_UNLOADING_CURVATURES_PER_M]]
    np.testing.assert_allclose(-unloading, loaded, rtol=0.3)
    # Information on z = (θ, log k1 warp, weft, bias) from the rows alone, k1 free.
    marg = {name: theta_stds(strip_information(1, "bias", 0.05, a), 1)[1][0] for name, a in shifts.items()}
    assert marg["fabric_rescale"] > 2.0 and marg["bending_friction"] < 0.25 * marg["fabric_rescale"], marg


def test_the_smallest_curvature_tells_a_saturating_bending_from_a_frictional_couple(fabric):
    """Both soften the loading rows at large curvature relative to the small ones, alike between
    50 and 150 1/m. A saturation (κ_s = 50 1/m) leaves the 10 1/m row nearly elastic, where a
    frictional couple's share is largest: with the three rows on warp, weft and bias both effects
    fitted together, and k1 free, are told apart; from the 50 and 150 1/m loading rows alone they
    are not, and with the unloading rows at 50 and 150 1/m they are again."""
    bench = BenchResponse(fabric)
    sat, fric = BendingSaturation(), BendingFriction()
    cuts = ("warp", "weft", "bias")
    a = {d: np.concatenate([bench.shift(sat, "pure_bending", d, 0.3), bench.shift(fric, "pure_bending", d, 0.3)], 1)
         for d in cuts}
    n = len(KES_CURVATURES_PER_M)
    assert KES_CURVATURES_PER_M[0] < 0.5 * KES_CURVATURES_PER_M[1]
    small, load = a["weft"][0], a["weft"][:n]
    assert abs(small[0]) < 0.3 * abs(load[-1, 0]) and small[1] > load[-1, 1] > 0, a["weft"]
    joint = theta_stds(sum(strip_information(2, d, 0.05, a[d][:n]) for d in cuts), 2)[1]
    upper = theta_stds(sum(strip_information(2, d, 0.05, a[d][1:n]) for d in cuts), 2)[1]
    assert np.all(joint < 0.5) and upper[0] > 0.8, (joint, upper)
    # The unloading branch: the saturation gives back what it took (the rows of its loading
    # branch), the couple resists the other way, so 50 and 150 1/m both ways separate them.
    for d in cuts:
        np.testing.assert_allclose(a[d][n:, 0], a[d][1:n, 0], rtol=1e-6, atol=1e-9)
        assert np.all(a[d][n:, 1] < 0)
    loop = theta_stds(sum(strip_information(2, d, 0.05, a[d][1:]) for d in cuts), 2)[1]
    assert np.all(loop < 0.5), loop


def test_only_a_pair_of_bias_strips_separates_an_asymmetry_from_the_bias_k1(fabric):
    """The base model reads both biases alike (one bias k1, the same moment at +45° and 135°). An
    extra stiffness along +45° (θ = 1: twice the bias rigidity there) lifts the +45° strip's moment
    about twice and leaves the 135° strip's as it is. So pure bending of a +45° strip alone takes it
    for a stiffer bias k1 (its two rows shift alike), and the pair of biases separates it."""
    bench = BenchResponse(fabric)
    plus, minus = PureBendingTest(fabric, "bias"), PureBendingTest(fabric, "counter_bias")
    terms = tuple(BiasAsymmetry().strip_terms(plus.mesh(), np.array([1.0])))
    for kappa in KES_CURVATURES_PER_M:
        base = plus.log_moment(kappa)
        assert base == pytest.approx(minus.log_moment(kappa), abs=1e-5)
        assert 1.8 < math.exp(plus.log_moment(kappa, extra_terms=terms) - base) < 2.3
        assert math.exp(minus.log_moment(kappa, extra_terms=terms) - base) == pytest.approx(1.0, abs=1e-3)
    info = {d: strip_information(1, d, 0.05, bench.shift(BiasAsymmetry(), "pure_bending", d, 0.3))
            for d in ("bias", "counter_bias")}
    alone = theta_stds(info["bias"], 1)[1][0]
    both = theta_stds(info["bias"] + info["counter_bias"], 1)[1][0]
    assert alone > 0.5 > 0.2 > both, (alone, both)
    assert np.allclose(strip_information(1, "counter_bias", 0.05), strip_information(1, "bias", 0.05))


def test_strip_information_is_the_outer_product_of_its_rows():
    """Rows (a, e_d)/σ: with a = 0 it is 1/σ² on log k1_d alone; a row adds a rank-one term."""
    f0 = strip_information(2, "weft", 0.05)
    expect = np.zeros((5, 5))
    expect[3, 3] = 1 / 0.05**2
    assert np.allclose(f0, expect)
    a = np.array([[0.2, -0.1], [0.05, 0.0]])
    f = strip_information(2, "weft", 0.05, a)
    v = np.concatenate([a, np.tile([0.0, 1.0, 0.0], (2, 1))], 1) / 0.05
    assert np.allclose(f, v.T @ v) and np.linalg.matrix_rank(f) == 2
