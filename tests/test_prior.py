"""Parameter prior fitted to the 618 real fabrics, and tag-based stretching kNN."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp
from scipy.stats import multivariate_normal

from drapejax.inverse.prior import FabricPrior, PriorError, default_prior
from drapejax.inverse.tags import (StretchKNN, TagError, TagVocab, encode_tag, load_catalogue,
                                   save_catalogue, synthetic_catalogue)
from drapejax.material import PARAM_KEYS, check, validity


@pytest.fixture(scope="module")
def prior():
    return default_prior()


@pytest.fixture(scope="module")
def data618(shared_data):
    d = np.genfromtxt(shared_data / "reference" / "fabrics_618_bending.csv", delimiter=",", skip_header=1)
    return {"density": d[:, 0], "k1": d[:, 1:4] * 1e-9, "k2": d[:, 4:7] * 1e-12}


@pytest.fixture(scope="module")
def samples(prior):
    return prior.sample(3000, seed=0)


def test_samples_valid_and_match_618_quantiles(samples, data618):
    assert bool(jnp.all(validity(samples)))
    check(samples, source="prior samples")  # also the unit-plausibility bounds
    for name, got, ref in [("density", samples.density, data618["density"]),
                           ("k1 warp", samples.bend_k1_warp, data618["k1"][:, 0]),
                           ("k1 weft", samples.bend_k1_weft, data618["k1"][:, 1])]:
        assert abs(np.median(got) / np.median(ref) - 1) < 0.15, name
        # The spread (5-95% range in decades) is also that of the data, within 20%.
        q = np.log10(np.percentile(got, [5, 95]))
        qr = np.log10(np.percentile(ref, [5, 95]))
        assert abs((q[1] - q[0]) / (qr[1] - qr[0]) - 1) < 0.2, name
    # Softening (k2 < 0) dominates, as for 613 of the 618 measured fabrics.
    assert np.mean(np.asarray(samples.bend_k2_warp) < 0) > 0.9


def test_stretch_prior_matches_literature_ranges(samples):
    a = np.stack([samples.stretch_alpha_warp, samples.stretch_alpha_weft], 1)
    assert 100 < np.median(a) < 1000  # tensile stiffness 1e2-1e3 N/m per width
    shear = np.asarray(samples.stretch_alpha_bias) / 2  # each bias spring carries alpha_bias
    assert 10 < np.median(shear) < 100
    assert np.percentile(samples.stretch_beta_warp, 99) < 25
    r = np.corrcoef(np.log(samples.density), np.log(samples.stretch_alpha_warp))[0, 1]
    assert 0.1 < r < 0.7  # heavier fabrics are (weakly) stiffer


def test_sampling_is_per_index_deterministic(prior, samples):
    sub = prior.sample_indices(np.array([2999, 7, 7]), seed=0)
    np.testing.assert_array_equal(np.asarray(sub.density), np.asarray(samples.density)[[2999, 7, 7]])
    other = prior.sample(10, seed=1)
    assert not np.allclose(np.asarray(other.density), np.asarray(samples.density)[:10])
    box = prior.sample_uniform_box(500, seed=0)
    assert bool(jnp.all(validity(box)))
    z = np.asarray(prior.to_latent(box))
    assert np.all(z >= np.asarray(prior.lo) - 1e-9) and np.all(z <= np.asarray(prior.hi) + 1e-9)
    # Uniform in log density: the four quarters of the log-density range are about equally full.
    lo, hi = float(prior.lo[0]), float(prior.hi[0])
    counts = np.histogram(z[:, 0], bins=4, range=(lo, hi))[0]
    assert counts.min() > 0.5 * counts.max()


def test_latent_roundtrip_and_log_prob_matches_scipy(prior, samples):
    p = jax.tree_util.tree_map(lambda a: a[:50], samples)
    z = np.asarray(prior.to_latent(p))
    back = eqx.filter_jit(prior.from_latent)(jnp.asarray(z))
    for k in PARAM_KEYS:
        np.testing.assert_allclose(np.asarray(getattr(back, k)), np.asarray(getattr(p, k)), rtol=1e-10, atol=1e-300)
    w, mu, cov = (np.asarray(a) for a in (prior.weights, prior.means, prior.covs))
    lp_b = logsumexp([np.log(w[k]) + multivariate_normal(mu[k], cov[k]).logpdf(z[:, :7]) for k in range(len(w))],
                     axis=0)
    cond = np.asarray(prior.stretch_mean) + np.outer(z[:, 0] - np.log(prior.rho_ref), np.asarray(prior.stretch_slope))
    lp_s = multivariate_normal(np.zeros(6), np.asarray(prior.stretch_cov)).logpdf(z[:, 7:] - cond)
    lp, g = eqx.filter_jit(jax.value_and_grad(lambda q: prior.log_prob(q).sum()))(p)
    np.testing.assert_allclose(float(lp), np.sum(lp_b + lp_s), rtol=1e-9)
    np.testing.assert_allclose(np.asarray(eqx.filter_jit(prior.log_prob)(p)), lp_b + lp_s, rtol=1e-9)
    assert np.all(np.isfinite(np.asarray(g.bend_k1_warp)))


def test_fit_json_roundtrip_and_errors(shared_data, tmp_path):
    fitted = FabricPrior.fit(shared_data / "reference" / "fabrics_618_bending.csv")
    again = FabricPrior.from_json(fitted.to_json())
    assert again.to_json() == fitted.to_json()
    assert "609 of 618" in fitted.source
    # The shipped prior was fitted to the same data: same component weights up to ordering.
    np.testing.assert_allclose(np.sort(np.asarray(fitted.weights)), np.sort(np.asarray(default_prior().weights)),
                               atol=0.02)
    bad = tmp_path / "bad.csv"
    bad.write_text("density, warp\n0.1, 2\n")
    with pytest.raises(PriorError, match="bad.csv: header"):
        FabricPrior.fit(bad)
    text = fitted.to_json().replace('"covariances"', '"covs"')
    with pytest.raises(PriorError, match="prior.json: missing field 'bending_gmm.covariances'"):
        FabricPrior.from_json(text, source="prior.json")


@pytest.fixture(scope="module")
def catalogue():
    return synthetic_catalogue(1500, seed=0)


def test_knn_beats_constant_predictor_in_10_fold_cv(catalogue):
    assert catalogue.source.startswith("SYNTHETIC")
    folds = StretchKNN(k=50).cross_validate(catalogue, folds=10)
    assert len(folds) == 10
    val = np.array([f["val_r2"] for f in folds])
    const = np.array([f["constant_val_r2"] for f in folds])
    assert np.all(const < 0.01)  # the training mean explains nothing out of fold
    assert np.all(val > const + 0.3)
    assert np.all(val < 0.95)  # tags do not determine stretching exactly (noise in the generator)


def test_knn_predict_and_catalogue_io(catalogue, tmp_path):
    path = tmp_path / "cat.csv"
    save_catalogue(catalogue, path)
    cat = load_catalogue(path)
    assert cat.source == catalogue.source and cat.fabric_id == catalogue.fabric_id
    np.testing.assert_allclose(cat.stretch, catalogue.stretch, rtol=1e-5)
    model = StretchKNN(k=50).fit(cat)
    denim = {"category": "Woven", "subcategory": "Twill", "type": "Denim",
             "composition": {"Cotton": 1.0}, "density_gsm": 380}
    jersey = {"category": "Knit", "subcategory": "Single", "type": "Jersey",
              "composition": {"Cotton": 0.92, "Spandex / Elastane": 0.08}, "density_gsm": 160}
    pd, pj = model.predict(denim), model.predict(jersey)
    # The prediction is the neighbours' mean of log(alpha/rho): recompute it from the catalogue.
    x = np.stack([encode_tag(t, model.vocab) for t in cat.tags])
    nbr = np.argsort(np.linalg.norm(x - encode_tag(denim, model.vocab), axis=1), kind="stable")[:50]
    rho = 1e-3 * np.array([cat.tags[i]["density_gsm"] for i in nbr])
    expect = 0.380 * np.exp(np.mean(np.log(cat.stretch[nbr, 0] / rho)))
    assert pd["stretch_alpha_warp"] == pytest.approx(expect, rel=0.05)
    assert pd["stretch_alpha_warp"] > 3 * pj["stretch_alpha_warp"]  # wovens are much stiffer than knits
    assert 0 < pd["spread"]["stretch_alpha_warp"] < 1.5
    with pytest.raises(TagError, match="unknown fabric type 'Tweed'"):
        encode_tag(dict(denim, type="Tweed"), model.vocab)
    with pytest.raises(TagError, match="must sum to 1"):
        encode_tag(dict(denim, composition={"Cotton": 0.5}), TagVocab(("Denim",), ("Cotton",)))
    bad = tmp_path / "bad.csv"
    bad.write_text(path.read_text().replace("Cotton:1", "Cotton=1", 1))
    with pytest.raises(TagError, match=r"bad.csv:\d+: column 'composition'"):
        load_catalogue(bad)
