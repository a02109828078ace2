"""Identifiability of candidate effects against k1 (Fisher information, ``diagnose.identifiability``).

A clean "mid" capture of the virtual lab on the default fit mesh, analysed at the lab's own rest
states (the ideal fit: the fabric that made the capture, in six fold states, over which the
fold-specific part of the response averages down): an off-centre specimen moves the rim's first
harmonic, which no k1 can; a heavier hem and a throw-away effect that rescales the bending
stiffness move the skirt as a change of k1 does.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax import refine
from drapejax.diagnose.identifiability import (BENCH_TESTS, STRIP_SETS, TENSILE_TEST, Identifiability,
                                               analyse_identifiability, strip_information, theta_stds)
from drapejax.effects import Effect, HeavyHem, OffCentre
from drapejax.energy import AbstractEnergy, Bending, HourglassControl, Membrane
from drapejax.io import CUT_ANGLES_DEG
from drapejax.material import DIRECTIONS

SPACING_M, RIM_SPACING_M = refine.FIT_SPACING_M, refine.FIT_RIM_SPACING_M


class _Scaled(AbstractEnergy):
    """``scale`` times another term's energy."""

    term: AbstractEnergy
    scale: jnp.ndarray

    def elements(self, mesh):
        return self.term.elements(mesh)

    def element_energy(self, xe, data, params):
        return self.scale * self.term.element_energy(xe, data, params)


class _TermRescale(Effect):
    """The energy of the ``scaled`` terms times 1 + θ: a change of their stiffness under another name."""

    name: str = eqx.field(static=True)
    scaled: tuple = eqx.field(static=True)
    label: str = eqx.field(static=True)

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([0.3])

    def terms(self, mesh, theta):
        return tuple(_Scaled(term=t, scale=theta[0]) for t in self.scaled)

    def describe(self, theta):
        return {self.label: 1.0 + float(theta[0])}


def StiffnessRescale():
    """Every bending rigidity times 1 + θ: exactly a uniform change of k1 (and k2)."""
    return _TermRescale(name="stiffness_rescale", scaled=(Bending(), HourglassControl()), label="bending_scale")


def MembraneRescale():
    """The membrane's energy times 1 + θ: exactly a change of every α."""
    return _TermRescale(name="membrane_rescale", scaled=(Membrane(),), label="membrane_scale")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """(fabric, fit mesh, rest states of drop seeds 1-6, targets of the seed-1 capture)."""
    from drapejax.io import load_measurement
    from drapejax.material import example_params
    from drapejax.virtual_lab import simulate_with_effects, write_capture

    p = example_params("mid")
    states = [simulate_with_effects(p, {}, spacing_m=SPACING_M, rim_spacing_m=RIM_SPACING_M, seed=s)
              for s in range(1, 7)]
    truth = {"params": p.to_dict(), "effects": {}, "mesh": {"spacing_m": SPACING_M, "rim_spacing_m": RIM_SPACING_M}}
    folder = write_capture(tmp_path_factory.mktemp("clean") / "c1", states[0][0], states[0][1], truth=truth,
                           areal_density_kg_m2=float(p.density), warp_angle_deg=0.0)
    m = load_measurement(folder)
    return p, refine.fit_mesh(m, SPACING_M, RIM_SPACING_M), [s[0] for s in states], refine.measured_targets(m)


@pytest.fixture(scope="module")
def result(lab):
    p, mesh, xs, targets = lab
    return analyse_identifiability(mesh, p, xs, targets, [OffCentre(), HeavyHem(), StiffnessRescale()], captures=4)


def test_fisher_matrices_are_symmetric_psd_on_theta_and_k1(result):
    for name, rec in result.items():
        f = np.asarray(rec["fisher"])
        n = len(rec["per_parameter"]["std_marginal"])
        assert f.shape == (n + 3, n + 3) and rec["columns"][n:] == [f"log_k1_{d}" for d in DIRECTIONS], name
        assert np.allclose(f, f.T, rtol=1e-12, atol=1e-12), name
        assert np.linalg.eigvalsh(f).min() >= -1e-9 * np.abs(f).max(), name
        assert np.all(np.diag(f)[n:] > 0), name  # the captures respond to every k1
        assert rec["rows"] == 13 and rec["captures"] == 4  # DC, fold, c1 ×2, hem, profile ×6, warp harmonics ×2


def test_an_offset_is_told_from_k1_and_a_heavier_hem_is_not(result):
    """An offset moves the rim's first harmonic, which no k1 can: it is identifiable with k1 free
    (k1 takes only the part of its variance that the fold states' own responses leave, 0.24 and
    0.55 here). A heavier hem pulls the skirt down as a softer fabric does (a baseline fitted to a
    hidden hem drifts to a softer k1): the captures cannot tell it from k1 (0.99)."""
    off, hem = result["off_centre"], result["heavy_hem"]
    assert off["identifiable"] and off["std_marginal"] < 0.5 and off["separated_by"] is None
    assert max(off["per_parameter"]["k1_confounding"]) < 0.8, off
    assert hem["k1_confounding"] > 0.9 and hem["k1_confounding"] > max(off["per_parameter"]["k1_confounding"]) + 0.2
    assert hem["std_conditional"] < 0.5 <= hem["std_marginal"] and not hem["identifiable"], hem
    assert "cannot be told apart from a change of k1" in hem["verdict"]
    assert hem["separated_by"] is None or hem["with_measurement"][hem["separated_by"]] < 0.5


def test_a_rescaled_bending_stiffness_is_fully_confounded_with_k1(result):
    """θ is a change of k1 by another name: its column lies in the span of the k1 columns, the
    captures see it (k1 known) but cannot tell it from k1, and nothing but a strip test, which
    pins k1 itself, separates them."""
    rec = result["stiffness_rescale"]
    f = np.asarray(rec["fisher"])
    explained = f[0, 1:] @ np.linalg.solve(f[1:, 1:], f[1:, 0]) / f[0, 0]
    assert explained > 0.99, explained
    assert rec["k1_confounding"] > 0.95 and not rec["identifiable"], rec
    assert rec["std_conditional"] < 0.5 < rec["std_marginal"]
    assert rec["with_measurement"]["another capture of the same specimen"] > 0.5
    assert rec["separated_by"] is None or "cantilever" in rec["separated_by"], rec["separated_by"]


def test_a_cantilever_strip_never_loosens_an_effect(result):
    """Information only adds: a strip along any direction leaves no std_marginal larger, on the
    captures' Fisher matrices and on random positive semi-definite ones."""
    rng = np.random.default_rng(0)
    mats = [(np.asarray(r["fisher"]), len(r["per_parameter"]["std_marginal"])) for r in result.values()]
    for n in (1, 2, 4):
        a = rng.normal(size=(n + 3, n + 6))
        mats.append((a @ a.T * rng.uniform(0.01, 100.0), n))
    for f, n in mats:
        cond, marg = theta_stds(f, n)
        for d in DIRECTIONS:
            c2, m2 = theta_stds(f + strip_information(n, d), n)
            assert np.all(m2 <= marg * (1 + 1e-9)) and np.allclose(c2, cond), (d, marg, m2)
        assert np.all(cond <= marg * (1 + 1e-9))
    for rec in result.values():
        assert all(v is None or v <= rec["std_marginal"] * (1 + 1e-9) for v in rec["with_measurement"].values()), rec


def test_a_rescaled_membrane_is_told_apart_only_with_the_membrane_measured(lab):
    """An effect that is a change of α by another name (θ in prior stds of 0.3 is 0.3 θ in log α):
    with the overall α scale free under a prior of std σ its column is the membrane column, so its
    variance gains exactly (σ / 0.3)²; a tensile test that pins the membrane (σ of a few per cent)
    gives the held-membrane std back. Freeing a nuisance never tightens an effect."""
    p, mesh, xs, targets = lab
    held = analyse_identifiability(mesh, p, xs[:2], targets, [MembraneRescale(), OffCentre()], captures=3)
    measured = analyse_identifiability(mesh, p, xs[:2], targets, [MembraneRescale()], captures=3,
                                       membrane_std=0.03)["membrane_rescale"]
    rec = held["membrane_rescale"]
    prior_in_theta = Identifiability().membrane_prior_std / 0.3
    assert rec["std_membrane_free"] ** 2 == pytest.approx(rec["std_marginal"] ** 2 + prior_in_theta**2, rel=0.1), rec
    assert measured["std_membrane_free"] == pytest.approx(measured["std_marginal"], rel=0.05), measured
    if rec["identifiable"]:
        assert rec["membrane_separated_by"] == TENSILE_TEST and "membrane stiffness known" in rec["verdict"]
    for r in held.values():
        assert r["std_membrane_free"] >= r["std_marginal"] * (1 - 1e-9), r


def test_a_capture_without_heights_is_offered_a_scan(lab):
    """Without a height map the rows are the silhouette's alone; the analysis differentiates the
    height rows too and weighs another capture with a scan (never looser than one without)."""
    p, mesh, xs, targets = lab
    bare = dataclasses.replace(targets, hem_m=None, rings_m=None, profile_m=None)
    rec = analyse_identifiability(mesh, p, xs[0], bare, [HeavyHem()], captures=1)["heavy_hem"]
    assert rec["rows"] == 6 and not rec["identifiable"]
    tried = rec["with_measurement"]
    scan = "another capture with a height map or 3D scan of the drape"
    assert scan in tried and tried[scan] <= tried["another capture of the same specimen"], tried


def test_strip_measurements_are_tried_fewest_strips_first():
    """After the captures: each single cut, then both biases (the pair that tells an asymmetry of
    the biases from the one bias k1), then warp/weft/bias, then all four; cantilever before pure
    bending. Each set's information is the sum of its strips'."""
    from drapejax.diagnose.identifiability import _measurements

    seen = []

    def bench(test, cut):
        seen.append((test, cut))
        return np.full((4, 4), 1.0 + list(CUT_ANGLES_DEG).index(cut))

    tried = list(_measurements(np.eye(4), None, [], bench))
    labels = [label for label, _ in tried]
    assert labels[0] == "another capture of the same specimen"
    for test in ("cantilever", "pure_bending"):
        mine = [(i, label) for i, label in enumerate(labels) if BENCH_TESTS[test][0] in label
                or BENCH_TESTS[test][1] in label]
        assert [label.rsplit("along ", 1)[1] for _, label in mine] == (
            ["the warp", "the weft", "the bias"] + [name for name, _ in STRIP_SETS])
        pair = dict(tried)[mine[3][1]]
        assert np.allclose(pair, 3.0 + 4.0)
    assert labels.index(f"{BENCH_TESTS['cantilever'][1]} along {STRIP_SETS[0][0]}") < labels.index(
        f"{BENCH_TESTS['cantilever'][1]} along warp, weft and bias")


def test_the_report_table_shows_the_verdict_and_the_measurement():
    from drapejax.diagnose.report import _tested_table

    rows = [{"name": n, "with": [], "accepted": False, "reason": "screen"} for n in ("a", "b", "c")]
    ident = {"a": {"identifiable": True, "std_marginal": 0.21, "separated_by": None},
             "b": {"identifiable": False, "std_marginal": 1.4, "separated_by": "a cantilever strip cut along the bias"},
             "c": {"identifiable": False, "std_marginal": 3.0, "separated_by": None}}
    html = _tested_table({"effects_tested": rows, "identifiability": ident})
    assert "yes (std 0.21)" in html and "no (std 1.4)" in html
    ident["a"]["membrane_separated_by"] = TENSILE_TEST
    assert "yes (std 0.21) with the membrane known" in _tested_table({"effects_tested": rows, "identifiability": ident})
    ident["a"]["membrane_separated_by"] = None
    assert "a cantilever strip cut along the bias" in html and "none of those tried" in html
    assert "measurement that would separate it" in _tested_table({"effects_tested": rows})
    # with nothing refitted (the baseline within the floor) the candidates' verdicts still show
    alone = _tested_table({"effects_tested": [], "identifiability": ident})
    assert "No effect was refitted" in alone and "no (std 1.4)" in alone and "none of those tried" in alone
    assert _tested_table({"effects_tested": []}) == "<p>No effect was refitted.</p>"


def test_settings_must_be_positive():
    with pytest.raises(ValueError, match="threshold"):
        Identifiability(threshold=0.0)
    with pytest.raises(ValueError, match="drops"):
        Identifiability(drops=-1)
