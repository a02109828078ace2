"""Bench tests on strips of the same fabric, an optional part of a measurement folder.

A drape test often comes with bench tests of strips cut from the same fabric: a cantilever strip
(Peirce 1930; ASTM D1388) or a pure bending test (Kawabata 1980, KES-FB2). They are listed under
``bench`` in ``measurement.json`` (docs/measurement-format.md), one object per reading:

* ``{"test": "cantilever", "direction": "weft", "overhang_m": 0.05, "width_m": 0.025,
  "tip_drop_m": 0.021}``: a strip cut along ``direction`` held flat up to a clamp edge with
  ``overhang_m`` of it beyond the edge; ``tip_drop_m`` is how far its free end (mean over the
  width) hangs below the clamp's top.
* ``{"test": "pure_bending", "direction": "bias", "curvature_per_m": 50, "moment_n": 4.9e-4}``:
  the moment per unit width (N·m/m, i.e. N) on the loading branch at an imposed uniform
  curvature (1/m).
* ``{"test": "pure_bending_unloading", "direction": "bias", "curvature_per_m": 50, "moment_n": 3.1e-4}``:
  the same test's moment on the unloading branch, the curvature coming back down from the
  test's largest (KES-FB2 loads to 250 1/m): the two branches differ by the hysteresis 2HB at
  that curvature, which an elastic nonlinearity does not show and a frictional couple does.
* ``{"test": "tensile", "direction": "warp", "strain": 0.01, "force_n_per_m": 6.1}``: a strip
  tensile test (Kawabata 1980, KES-FB1; ISO 13934-1): the force per unit width (N/m) at an
  imposed nominal strain (a fraction: 1 % is 0.01), long edges free. It sets the membrane
  (``refine.tensile``), which the bending readings do not feel.

``direction`` is ``"warp"``, ``"weft"``, ``"bias"`` (45° from the warp towards the weft) or
``"counter_bias"`` (the other bias, 135° from the warp). The base model has one bias rigidity
(``K1_OF_CUT``), so a pair of strips along both biases is what tells it from an effect that
stiffens one bias only (``effects.bias_asymmetry``; seed 001, Fig. 11b). ``_parse_bench``
validates the list and returns ``BenchRecord`` objects; a reading in the wrong unit (millimetres
as metres, µN as N) is refused with the field named.
"""

from __future__ import annotations

import dataclasses
import math

from .measurement import _Fail

BENCH_KEY = "bench"
CUT_ANGLES_DEG = {"warp": 0.0, "weft": 90.0, "bias": 45.0, "counter_bias": 135.0}
"""The angle of a strip's axis from the warp (towards the weft), per ``direction`` a bench reading may name."""
K1_OF_CUT = {"warp": "warp", "weft": "weft", "bias": "bias", "counter_bias": "bias"}
"""The base model's k1 (``bend_k1_<name>``) a strip cut along each direction measures: both biases
read the one bias rigidity of a fabric that is mirror-symmetric about its warp."""
DIRECTIONS = tuple(CUT_ANGLES_DEG)
BENCH_FIELDS = {"cantilever": ("overhang_m", "width_m", "tip_drop_m"),
                "pure_bending": ("curvature_per_m", "moment_n"),
                "pure_bending_unloading": ("curvature_per_m", "moment_n"),
                "tensile": ("strain", "force_n_per_m")}
"""The numbers each bench test records (all positive, SI units); the last is the reading itself."""
BENDING_TESTS = ("cantilever", "pure_bending", "pure_bending_unloading")
"""The bench tests that load a strip in bending (what ``diagnose.bench`` tests effects on)."""
READING_STD = 0.05
"""Repeatability of a bench reading, as a std of the log k1 it implies along its cut: a few per
cent (a strip test's own scatter, and the bending model's few per cent against the cantilever
master curve, ``validate.TOLERANCE``). The identifiability analysis, the bench stage of
``diagnose`` and the virtual lab's readings share it."""

MAX_STRIP_M = 0.5
"""Longest overhang or widest strip accepted, m (a cantilever tester takes strips of 15-25 cm)."""
MAX_CURVATURE_PER_M = 1000.0
"""Largest imposed curvature accepted, 1/m (KES-FB2 bends to ±250 1/m)."""
MAX_MOMENT_N = 1.0
"""Largest moment per unit width accepted, N·m/m (a stiff denim at 250 1/m carries about 1e-2)."""
MAX_STRAIN = 0.5
"""Largest tensile strain accepted, a fraction (KES-FB1 stops at 500 gf/cm, a few per cent for a woven)."""
MAX_FORCE_N_PER_M = 1.0e5
"""Largest tensile force per unit width accepted, N/m (a woven's strip breaks at about 1e4)."""


@dataclasses.dataclass(frozen=True)
class BenchRecord:
    """One bench reading on a strip cut along ``direction`` (see module docstring).

    Attributes:
        test: a key of ``BENCH_FIELDS``.
        direction: "warp", "weft", "bias" or "counter_bias" (``CUT_ANGLES_DEG``).
        values: the test's numbers by name (``BENCH_FIELDS[test]``), SI units.
    """

    test: str
    direction: str
    values: dict

    def __post_init__(self):
        if self.test not in BENCH_FIELDS:
            raise ValueError(f"bench test must be one of {tuple(BENCH_FIELDS)}, got {self.test!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"bench direction must be one of {DIRECTIONS}, got {self.direction!r}")
        missing = sorted(set(BENCH_FIELDS[self.test]) - set(self.values))
        if missing:
            raise ValueError(f"a {self.test} reading needs {missing}")

    @property
    def measured(self) -> float:
        """The reading itself: the tip drop (m), the moment per unit width (N) or the tensile force
        per unit width (N/m)."""
        return float(self.values[BENCH_FIELDS[self.test][-1]])

    def with_reading(self, value: float) -> "BenchRecord":
        """The same test with ``value`` as its reading (the virtual lab's simulated strips)."""
        return BenchRecord(self.test, self.direction, {**self.values, BENCH_FIELDS[self.test][-1]: float(value)})

    def to_json(self) -> dict:
        return {"test": self.test, "direction": self.direction, **{k: float(v) for k, v in self.values.items()}}


def _limit(field: str) -> tuple[float, str]:
    if field == "curvature_per_m":
        return MAX_CURVATURE_PER_M, "1/m"
    if field == "moment_n":
        return MAX_MOMENT_N, "N·m/m = N; 490 µN is 4.9e-4"
    if field == "strain":
        return MAX_STRAIN, "a fraction: 1 % is 0.01"
    if field == "force_n_per_m":
        return MAX_FORCE_N_PER_M, "N per metre of width: 5 N on a 5 cm strip is 100"
    return MAX_STRIP_M, "metres: 50 mm is 0.05"


def _parse_bench(raw, fail: _Fail) -> tuple[BenchRecord, ...]:
    """Validate the ``bench`` list of measurement.json (absent or null: none)."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise fail.json(BENCH_KEY, f"must be a list of bench readings, got {raw!r}")
    out = []
    for i, entry in enumerate(raw):
        where = f"{BENCH_KEY}[{i}]"
        if not isinstance(entry, dict):
            raise fail.json(where, f"must be a JSON object, got {entry!r}")
        test = entry.get("test")
        if test not in BENCH_FIELDS:
            raise fail.json(f"{where}.test", f"unknown bench test {test!r}; expected one of {sorted(BENCH_FIELDS)}")
        direction = entry.get("direction")
        if direction not in DIRECTIONS:
            raise fail.json(f"{where}.direction", f"must be one of {list(DIRECTIONS)}, got {direction!r}")
        values = {}
        for field in BENCH_FIELDS[test]:
            if field not in entry:
                raise fail.json(f"{where}.{field}", f"missing required key of a {test} reading")
            v = entry[field]
            x = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan
            if not (math.isfinite(x) and x > 0):
                raise fail.json(f"{where}.{field}", f"must be a positive finite number, got {v!r}")
            top, unit = _limit(field)
            if x > top:
                raise fail.json(f"{where}.{field}",
                                f"{x:g} is beyond any bench test (at most {top:g} accepted; {unit})")
            values[field] = x
        if test == "cantilever" and values["tip_drop_m"] >= values["overhang_m"]:
            raise fail.json(f"{where}.tip_drop_m", f"a strip {values['overhang_m']:g} m long cannot hang "
                                                    f"{values['tip_drop_m']:g} m below its clamp")
        out.append(BenchRecord(test, direction, values))
    return tuple(out)


__all__ = ["BenchRecord", "BENCH_FIELDS", "BENCH_KEY", "BENDING_TESTS", "CUT_ANGLES_DEG", "K1_OF_CUT", "READING_STD"]
