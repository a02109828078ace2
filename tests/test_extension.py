"""A new effect is one class and one registry entry: the diagnosis names no effect.

``drapejax.diagnose`` reaches every candidate through ``drapejax.effects.REGISTRY`` and the hooks
of ``Effect`` (signature, admissibility, label, place), so an effect defined here, in the test,
and registered for its duration is ranked, gated, screened, selected and reported like the
library's own. Drops and refits are stand-ins (no simulation), so this runs in seconds.

Likewise ``drapejax.refine`` reaches every observation type through ``drapejax.observe.REGISTRY``
(``observe.types.AbstractObservation``): one defined and registered here is measured on a real
capture and scored by the fit's misfit, on a coarse simulated rest state.
"""

from __future__ import annotations

import ast
import dataclasses
import re
from pathlib import Path
from types import SimpleNamespace
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax import diagnose, effects, observe, refine
from drapejax.diagnose import Views, analyse_views, select, write_report
from drapejax.effects import Effect, candidate_effects
from drapejax.energy import AbstractEnergy, total_energy
from drapejax.io import Measurement, load_measurement
from drapejax.material import G, example_params
from drapejax.mesh import cusick_mesh
from drapejax.observe import pixel_centres
from drapejax.refine import FitResult
from drapejax.solve import drape

DIAGNOSE = Path(diagnose.__file__).resolve().parent
DISK = 0.09
EXT = 0.16
BANDS = ("near_disc", "mid", "hem")


class UniformLoadTerm(AbstractEnergy):
    """An extra areal weight, ``ratio`` times the fabric's, all over the specimen: ratio·ρ·A_i·g·z_i."""

    ratio: jnp.ndarray

    def elements(self, mesh):
        return jnp.arange(mesh.n_verts)[:, None], mesh.vertex_area

    def element_energy(self, xe, area, params):
        return self.ratio * params.density * area * G * xe[0, 2]


class UniformLoad(Effect):
    """Throw-away effect: the specimen heavier than its areal density says (a finish, moisture)."""

    name: str = eqx.field(static=True, default="uniform_load")
    label = "uniform extra areal load"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([0.2])

    def lower_bound(self):
        return np.array([-1.0])  # the specimen's weight cannot be negative

    def terms(self, mesh, theta):
        return (UniformLoadTerm(ratio=theta[0]),)

    def describe(self, theta):
        return {"extra_areal_load_ratio": float(theta[0])}

    def signature(self, evidence):
        """A heavier skirt hangs lower all the way out: the share of radial bands where it does."""
        return float(np.mean([evidence.band_lower(b) for b in BANDS]))

    def inadmissible(self, evidence):
        if not evidence.band_lower("mid"):
            return "the skirt does not hang lower than simulated mid-way out"
        return None

    def where(self, values):
        return "all over the specimen"


@pytest.fixture
def load(monkeypatch):
    """``UniformLoad`` registered for the test's duration only."""
    effect = UniformLoad()
    monkeypatch.setitem(effects.REGISTRY, effect.name, effect)
    return effect


def _measurement() -> Measurement:
    return Measurement(None, "cusick", 0.15, DISK, 0.2, 0.0, None, None, None, None, None, None, None, None, None, {})


def _views(slope: float, n: int = 128) -> Views:
    """A round skirt (12 cm rim, six folds) whose height falls by ``slope`` m per m beyond the disc."""
    c = pixel_centres(n, EXT)
    x, y = np.meshgrid(c, c[::-1])
    rho, phi = np.hypot(x, y), np.arctan2(y, x)
    inside = rho <= 0.12 + 0.012 * np.cos(6 * phi) + 0.006 * np.cos(4 * phi)
    z = -slope * np.clip(rho - DISK, 0.0, None)
    return Views(np.where(inside, 255, 0).astype(np.uint8), np.where(inside, z, np.nan), EXT)


def _residual(measured_slope: float):
    """Residual of a capture whose skirt falls at ``measured_slope`` against a simulated 1.5."""
    return analyse_views(_measurement(), _views(measured_slope), _views(1.5))


def _string_literals(tree: ast.AST) -> list[ast.Constant]:
    """The module's string constants that code uses: not its docstrings or other bare string
    statements (prose), f-string parts included."""
    prose = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Expr)
             and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)}
    return [node for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in prose]


def _effects_named(source: str) -> list[str]:
    """Where ``source`` (a module's text) names a registered effect in code: a string literal
    holding its name (not inside a longer identifier), or a reference to its class."""
    names = {e.name for e in candidate_effects()}
    classes = {type(e).__name__ for e in candidate_effects()}
    tree, found = ast.parse(source), []
    for node in _string_literals(tree):
        hits = [n for n in names if re.search(rf"(?<![A-Za-z0-9]){re.escape(n)}(?![A-Za-z0-9])", node.value)]
        found += [f"{node.lineno}: string {n!r}" for n in hits]
    for node in ast.walk(tree):
        ident = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
        aliases = [a.name for a in node.names] if isinstance(node, (ast.Import, ast.ImportFrom)) else []
        found += [f"{node.lineno}: refers to {c}" for c in classes if c == ident or c in aliases]
    return found


def test_no_registered_effect_is_named_in_diagnose():
    """No string literal in ``drapejax/diagnose`` holds a registered effect's name, and no code
    there refers to an effect class: the diagnosis learns every effect from the registry."""
    paths = sorted(DIAGNOSE.glob("*.py"))
    assert len(candidate_effects()) >= 9 and {"select.py", "signatures.py", "report_text.py"} <= {p.name for p in paths}
    found = [f"{path.name}:{line}" for path in paths for line in _effects_named(path.read_text(encoding="utf-8"))]
    assert len(found) == 0, "effects named in drapejax/diagnose:\n" + "\n".join(found)


def test_the_name_check_finds_names_in_code_not_in_prose():
    """The check above flags a name compared as a string, built into an f-string, or a class
    imported, and leaves docstrings and longer identifiers alone."""
    source = ('"""Prose about off_centre."""\n'
              'from ..effects import OffCentre\n\n\n'
              'def f(name, values):\n'
              '    """Special-cases off_centre."""\n'
              '    k = values["specimen_centre_dx_mm"]\n'
              '    return name == "off_centre" or f"{name}_heavy_hem" or k\n')
    assert _effects_named(source) == ["8: string 'off_centre'", "8: string 'heavy_hem'", "2: refers to OffCentre"]


def test_every_registered_effect_carries_its_diagnosis_hooks():
    """Each library effect says what it is, where it acts and what residual it leaves (its own
    ``signature``, None where it has none to look for): the diagnosis has no other source."""
    for e in candidate_effects():
        assert isinstance(type(e).label, str) and type(e).label, e.name
        assert type(e).signature is not Effect.signature, e.name
        assert type(e).where is not Effect.where, e.name


def test_a_new_effect_is_ranked_gated_and_weighs_like_the_library_ones(load):
    """Registered here and nowhere else, the effect is among the diagnosis's candidates, its
    signature is scored and ranks it first on a skirt that hangs lower all the way out, its own
    admissibility rules it out on one that hangs higher, and its energy is the extra weight's."""
    assert candidate_effects()[-1] is load and select.combine(candidate_effects()).effects[-1] is load
    heavier, lighter = _residual(1.8), _residual(1.2)
    assert all(heavier.bands[b]["height_mm"] < 0 for b in BANDS)
    scores = select.signature_scores(heavier)
    assert scores[load.name] == 1.0 and max(scores.values()) == 1.0
    assert load.name in scores and set(scores) <= {e.name for e in candidate_effects()}
    (first, score), *_ = select.rank(heavier, candidate_effects())
    assert first is load and score == 1.0
    assert select.signature_scores(lighter)[load.name] == 0.0
    assert select.inadmissible(load.name, [heavier]) is None
    assert "hang lower" in select.inadmissible(load.name, [lighter])
    assert select.inadmissible(UniformLoad(), [lighter]) == select.inadmissible(load.name, [lighter])

    mesh, p = cusick_mesh(0.03), example_params("mid")
    x = jnp.asarray(mesh.rest).at[:, 2].set(-0.01)
    assert float(total_energy(load.terms(mesh, jnp.zeros(1)), x, mesh, p)) == 0.0
    np.testing.assert_allclose(float(total_energy(load.terms(mesh, jnp.array([0.5])), x, mesh, p)),
                               0.5 * p.density * G * float(jnp.sum(mesh.vertex_area)) * -0.01, rtol=1e-5)


def _model(ratio: float) -> dict:
    held = {"iou": 0.93, "dc_abs": 0.012, "spectral_mm": 3.1, "scan_mm": 2.2}
    return {"params": {"density": 0.2, "bend_k1_warp": 1.6e-05, "bend_k1_weft": 1.9e-05}, "std": None,
            "error": held, "heldout_error": [held], "loss": 40.0, "error_ratio": ratio, "heldout_misfit": [9.0],
            "misfit_within_noise": False, "expected": None}


def test_the_search_screens_selects_and_reports_a_new_effect(load, monkeypatch, tmp_path):
    """The whole search over the default candidates, with stand-in drops in which the new effect
    alone lowers the misfit: its signature ranks it, the library's offset test rules off-centre
    out on these centred captures, the screen drops and confirms it, and it is selected; the
    report then names it with its label, its strength and where it acts."""
    rep = _residual(1.8)
    confirmed = {"null": 9.0, load.name: 3.0}

    def screen_loss(name, theta):  # the new effect best at its largest probe, every other one behind the null
        return 2.0 - theta[-1] if name == load.name else 9.5 if name != "null" else 10.0

    def fake_drops(prob, points):
        return [{"theta": th, "seed": s, "x": np.zeros((3, 3)), "n_residuals": 15,
                 "loss": screen_loss(prob.name, th)} for th, s in points]

    def fake_confirm(ms, effs, theta, **kw):
        return {"misfit": confirmed.get(effs[-1].name if effs else "null", 8.9), "error_ratio": 1.0}

    def fake_trial(ms, names, fit, mesh, floor):
        return select.Trial(tuple(names), fit, rep, [{}], [], 1.0, 0.0, [fit.loss], False, 15)

    def fake_fit(m, *, start, **kw):
        return FitResult(None, np.asarray(start.theta), np.eye(len(start.theta)), start.x, 2.0, 1.5, 3, "converged",
                         [1.5], 15)

    monkeypatch.setattr(select.refine, "measured_targets", lambda m: None)
    monkeypatch.setattr(select, "effect_problem",
                        lambda targets, effs, *a, **kw: SimpleNamespace(name=effs[-1].name if effs else "null",
                                                                        programs=lambda **kw: []))
    monkeypatch.setattr(select, "_drops", fake_drops)
    monkeypatch.setattr(select, "confirm_misfit", fake_confirm)
    monkeypatch.setattr(select, "confirm_misfits",
                        lambda ms, models, **kw: [fake_confirm(ms, effs, th, **kw) for effs, th in models])
    monkeypatch.setattr(select, "_trial", fake_trial)
    monkeypatch.setattr(select, "evaluate_baseline", lambda ms, fit, mesh, floor: select.Trial(
        (), fit, rep, [{}], [], 2.0, 0.0, [20.0], False, 15))
    monkeypatch.setattr(select.refine, "fit", fake_fit)
    monkeypatch.setattr(select, "_on_fit_rows", lambda m, tr, effs, **kw: tr)
    base = FitResult(None, np.zeros(3), np.eye(3), np.zeros((3, 3)), 20.0, 20.0, 0, "converged", [20.0], 15)
    sel = select.search([None, None], base_fit=base, init=None, candidates=candidate_effects(),
                        mesh=SimpleNamespace(), spacing_m=0.02, max_effects=1, expected_seeds=None,
                        screen=select.Screen(k_factors=(1.0,), widen=0, polish=0))

    assert sel.selected == [load] and sel.signatures[load.name] == 1.0
    rows = {r["name"]: r for r in sel.tested}
    assert set(rows) == {e.name for e in candidate_effects()}
    assert rows[load.name]["accepted"] and rows[load.name]["signature"] == 1.0
    assert rows[load.name]["screen_loss"] == pytest.approx(1.6) and rows[load.name]["confirm_misfit"] == 3.0
    assert "first harmonic" in rows["off_centre"]["reason"] and "screen_loss" not in rows["off_centre"]
    assert list(sel.screen[0])[:2] == ["null", load.name]  # screened first, as ranked
    values = sel.final.summary(sel.selected)["values"]
    assert values == {load.name: {"theta": [0.4], "extra_areal_load_ratio": 0.4}}  # the +2 prior std probe

    result = {"baseline": _model(2.0), "final": _model(1.0), "effects_tested": sel.tested,
              "selected": [e.name for e in sel.selected], "selected_values": values, "density_normalized": False,
              "within_noise_floor": False, "baseline_within_noise_floor": False,
              "noise_floor": {"iou": 0.9, "dc_abs": 0.03, "spectral_mm": 6.0, "scan_mm": 3.0},
              "reason": sel.reason, "folders": [], "report": None}
    text = write_report(tmp_path / "report.html", result, rep, rep).read_text(encoding="utf-8")
    head = text[:text.index("<table")]
    assert f"<b>{load.name}</b> (uniform extra areal load)" in head
    assert "extra areal load ratio 0.4" in head and "Where: all over the specimen." in head


# A new observation type is one class and one registry entry: the fit's misfit names no observation.

class HemBand(observe.AbstractObservation):
    """Throw-away observation: the mean top-view fabric height in the outer 10 mm band of the
    skirt (105–115 mm from the axis), one misfit row over a 5 mm noise floor."""

    name: ClassVar[str] = "hem_band"
    band_m: ClassVar[tuple[float, float]] = (0.105, 0.115)
    sigma_m: ClassVar[float] = 0.005

    def _band_mean(self, z, extent_m):
        c = pixel_centres(z.shape[0], extent_m)
        x, y = np.meshgrid(c, c[::-1])
        rho = np.hypot(x, y)
        sel = (rho >= self.band_m[0]) & (rho < self.band_m[1]) & np.isfinite(z)
        return np.array([float(np.asarray(z, float)[sel].mean())])

    def present(self, m):
        return m.height is not None

    def render(self, verts, faces, *, n=256, extent_m=EXT):
        return observe.height_map(np.asarray(verts, float), np.asarray(faces), n=n, extent_m=extent_m)

    def soft(self, x, mesh, *, n=64, extent_m=EXT):
        return observe.soft_height_map(x, mesh.faces, sharpness=jnp.asarray(n / extent_m), n=n, extent_m=extent_m)

    def network_input(self, m):
        return None

    def target(self, m):
        return self._band_mean(np.asarray(m.height, float), m.height_extent_m)

    def features(self, x, mesh):
        return self._band_mean(self.render(x, mesh.faces), EXT)

    def soft_features(self, x, mesh, spacing_m):
        z = self.soft(x, mesh)
        c = jnp.asarray(pixel_centres(z.shape[0], EXT))
        rho = jnp.hypot(c[None, :], c[::-1, None])
        sel = (rho >= self.band_m[0]) & (rho < self.band_m[1]) & jnp.isfinite(z)
        return (jnp.sum(jnp.where(sel, z, 0.0)) / jnp.sum(sel))[None]

    def misfit_rows(self, measured, simulated):
        return (simulated - measured) / self.sigma_m


@pytest.fixture(scope="module")
def capture_and_rest(shared_data):
    """A real capture with a scan, silhouette and height map, and a coarse simulated rest state."""
    m = load_measurement(shared_data / "real_cusick" / "bdp_f01_sample_10_capture_1")
    mesh, p = cusick_mesh(0.03), example_params("mid")
    return m, mesh, p, np.asarray(drape(mesh, p, 0).x)


def test_a_new_observation_adds_its_row_to_the_fit(capture_and_rest, monkeypatch):
    """Registered here and nowhere else, the observation's measured feature lands in the targets of
    a capture that has it, and the fit's misfit gains exactly its row (appended after the library's
    rows, which stay as they were) and the Jacobian a row for it; unregistered, or on a capture
    without a height map, it contributes nothing."""
    m, mesh, p, x = capture_and_rest
    before = refine.measured_targets(m)
    assert "hem_band" not in before.extra and list(observe.REGISTRY)[:3] == ["silhouette", "height_map",
                                                                              "warp_harmonic"]
    base = refine.Misfit(mesh, before)
    r0 = base.whiten(base.hard(x))

    band = HemBand()
    monkeypatch.setitem(observe.REGISTRY, band.name, band)
    after = refine.measured_targets(m)
    np.testing.assert_array_equal(after.extra["hem_band"], band.target(m))
    assert refine.Misfit(mesh, before).n_rows == base.n_rows  # targets without it: no row
    mf = refine.Misfit(mesh, after)
    assert mf.n_rows == base.n_rows + 1 and mf.own_observations == (band,)
    r1 = mf.whiten(mf.hard(x))
    row = (band.features(x, mesh)[0] - after.extra["hem_band"][0]) / HemBand.sigma_m
    np.testing.assert_array_equal(r1[:-1], r0)
    assert r1[-1] == row and row != 0.0
    assert mf.loss(x) == pytest.approx(base.loss(x) + 0.5 * row**2, rel=1e-12)

    no_height = dataclasses.replace(m, height=None, height_extent_m=None, scan_vertices=None, scan_faces=None)
    assert not band.present(no_height) and "hem_band" not in refine.measured_targets(no_height).extra

    prob = refine.Problem(mesh, after, p, (), np.zeros(3), np.array([np.log(3.0), 0.25]), 0.03)
    r, j = prob.evaluate(np.zeros(3), x, jacobian=True)
    assert r.shape == (mf.n_rows + 3,) and j.shape == (mf.n_rows + 3, 3) and r[mf.n_rows - 1] == row
    assert np.all(np.isfinite(j[mf.n_rows - 1])) and np.any(j[mf.n_rows - 1] != 0.0)

    monkeypatch.delitem(observe.REGISTRY, band.name)
    assert "hem_band" not in refine.measured_targets(m).extra
    assert refine.Misfit(mesh, after).n_rows == base.n_rows  # unregistered: its stored target is not scored
