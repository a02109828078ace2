"""Fabric tag information and tag → stretching regression (seed 001 §6.1, Table 1).

A fabric tag is the spec's ``"tag"`` entry: ``{"category", "subcategory", "type",
"composition": {fibre: fraction}, "density_gsm"}``. Stretching parameters are regressed from
the tag with a k-nearest-neighbour model (k = 50) on one-hot type + fibre composition +
log density, predicting density-normalised, log-scaled stiffness log(α/ρ) and β.

Catalogue CSV columns: ``fabric_id, category, subcategory, type, composition, density_gsm``
and the six ``STRETCH_KEYS`` in SI (α in N/m, β dimensionless). ``composition`` is written
``"Cotton:0.98;Spandex / Elastane:0.02"``. Lines starting with ``#`` are comments.

No real tag catalogue ships with drapejax: ``synthetic_catalogue`` makes a SYNTHETIC one.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
from jaxtyping import Float

from ..material import STRETCH_KEYS

CATALOGUE_COLUMNS = ("fabric_id", "category", "subcategory", "type", "composition",
                     "density_gsm") + STRETCH_KEYS

DENSITY_REF_GSM = 200.0
"""Density feature is log(density_gsm / DENSITY_REF_GSM): a factor 2 in density counts like
swapping 70% of the fibre composition in the kNN distance."""


class TagError(ValueError):
    """A malformed tag or catalogue; the message names the file, line and field."""


@dataclasses.dataclass(frozen=True, eq=False)
class Catalogue:
    """Fabrics with tags and stretching parameters.

    Attributes:
        fabric_id: (n,) identifiers.
        tags: (n,) tag dicts in the spec's ``"tag"`` format.
        stretch: (n, 6) stretching parameters in ``STRETCH_KEYS`` order (α N/m, β 1).
        source: provenance ("SYNTHETIC ..." for generated catalogues).
    """

    fabric_id: tuple[str, ...]
    tags: tuple[dict, ...]
    stretch: Float[np.ndarray, "n 6"]
    source: str

    def __len__(self) -> int:
        return len(self.fabric_id)


@dataclasses.dataclass(frozen=True)
class TagVocab:
    """The fabric types and fibres a tag encoding knows (fixes the feature layout)."""

    types: tuple[str, ...]
    fibres: tuple[str, ...]

    @classmethod
    def from_catalogue(cls, cat: Catalogue) -> "TagVocab":
        types = sorted({t["type"] for t in cat.tags})
        fibres = sorted({f for t in cat.tags for f in t["composition"]})
        return cls(tuple(types), tuple(fibres))

    @property
    def size(self) -> int:
        return len(self.types) + len(self.fibres) + 1


def parse_composition(text: str, *, where: str = "composition") -> dict[str, float]:
    """Parse ``"Cotton:0.98;Spandex / Elastane:0.02"`` into fractions summing to 1."""
    comp: dict[str, float] = {}
    for part in str(text).split(";"):
        if not part.strip():
            continue
        name, sep, frac = part.rpartition(":")
        try:
            value = float(frac)
        except ValueError:
            value = float("nan")
        if not sep or not name.strip() or not 0.0 < value <= 1.0:
            raise TagError(f"{where}: bad entry {part!r} in {text!r}; expected 'Fibre:fraction' "
                           f"with 0 < fraction <= 1, entries separated by ';'")
        comp[name.strip()] = comp.get(name.strip(), 0.0) + value
    return _normalised(comp, where)


def _normalised(comp: dict, where: str) -> dict[str, float]:
    total = sum(comp.values())
    if not comp or abs(total - 1.0) > 0.02:
        raise TagError(f"{where}: fibre fractions {comp} must sum to 1 (got {total:.3f})")
    return {k: v / total for k, v in comp.items()}


def format_composition(comp: dict[str, float]) -> str:
    """Inverse of ``parse_composition``."""
    return ";".join(f"{k}:{v:.4g}" for k, v in comp.items())


def load_catalogue(csv_path) -> Catalogue:
    """Read a tag catalogue CSV (``CATALOGUE_COLUMNS``); errors name the file, line and column."""
    path = Path(csv_path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise TagError(f"{path}: catalogue file not found") from None
    comments = [ln[1:].strip() for ln in text.splitlines() if ln.startswith("#")]
    rows = csv.reader(ln for ln in text.splitlines() if not ln.startswith("#"))
    header = next(rows, None)
    if header is None or [h.strip() for h in header] != list(CATALOGUE_COLUMNS):
        raise TagError(f"{path}: header must be {','.join(CATALOGUE_COLUMNS)}; got {header}")
    ids, tags, stretch = [], [], []
    for lineno, row in enumerate(rows, start=2 + len(comments)):
        if not row:
            continue
        where = f"{path}:{lineno}"
        if len(row) != len(CATALOGUE_COLUMNS):
            raise TagError(f"{where}: expected {len(CATALOGUE_COLUMNS)} columns, got {len(row)}")
        rec = dict(zip(CATALOGUE_COLUMNS, (c.strip() for c in row)))
        nums = {}
        for key in ("density_gsm",) + STRETCH_KEYS:
            try:
                nums[key] = float(rec[key])
            except ValueError:
                raise TagError(f"{where}: column '{key}' must be a number, got {rec[key]!r}") from None
            if not np.isfinite(nums[key]):
                raise TagError(f"{where}: column '{key}' is not finite")
        for key in ("density_gsm",) + STRETCH_KEYS[:3]:
            if nums[key] <= 0:
                raise TagError(f"{where}: column '{key}' must be positive, got {nums[key]}")
        for key in ("category", "type"):
            if not rec[key]:
                raise TagError(f"{where}: column '{key}' is empty")
        tags.append({"category": rec["category"], "subcategory": rec["subcategory"],
                     "type": rec["type"],
                     "composition": parse_composition(rec["composition"], where=f"{where}: column 'composition'"),
                     "density_gsm": nums["density_gsm"]})
        ids.append(rec["fabric_id"])
        stretch.append([nums[k] for k in STRETCH_KEYS])
    if not ids:
        raise TagError(f"{path}: catalogue has no rows")
    source = " ".join(comments) or str(path)
    return Catalogue(tuple(ids), tuple(tags), np.asarray(stretch, float), source)


def save_catalogue(cat: Catalogue, csv_path) -> None:
    """Write ``cat`` as a catalogue CSV; ``cat.source`` goes into a leading ``#`` comment."""
    with open(csv_path, "w", newline="") as f:
        f.write(f"# {cat.source}\n")
        w = csv.writer(f)
        w.writerow(CATALOGUE_COLUMNS)
        for fid, tag, s in zip(cat.fabric_id, cat.tags, cat.stretch):
            w.writerow([fid, tag["category"], tag["subcategory"], tag["type"],
                        format_composition(tag["composition"]), f"{tag['density_gsm']:.6g}"]
                       + [f"{v:.6g}" for v in s])


def encode_tag(tag: dict, vocab: TagVocab) -> Float[np.ndarray, " f"]:
    """Feature vector [one-hot type, fibre fractions, log(density_gsm / 200)] of one tag.

    Raises ``TagError`` for a missing field or a type/fibre the vocabulary does not know.
    """
    for key in ("type", "composition", "density_gsm"):
        if key not in tag:
            raise TagError(f"tag: missing field '{key}' (got {sorted(tag)})")
    if tag["type"] not in vocab.types:
        raise TagError(f"tag: unknown fabric type {tag['type']!r}; known: {list(vocab.types)}")
    comp = tag["composition"]
    if isinstance(comp, str):
        comp = parse_composition(comp, where="tag: 'composition'")
    elif isinstance(comp, dict):
        comp = _normalised({k: float(v) for k, v in comp.items()}, "tag: 'composition'")
    else:
        raise TagError(f"tag: 'composition' must be a dict of fibre fractions, got {comp!r}")
    unknown = sorted(set(comp) - set(vocab.fibres))
    if unknown:
        raise TagError(f"tag: unknown fibre(s) {unknown} in 'composition'; known: {list(vocab.fibres)}")
    gsm = tag["density_gsm"]
    if isinstance(gsm, bool) or not isinstance(gsm, (int, float)) or not gsm > 0:
        raise TagError(f"tag: 'density_gsm' must be a positive number (g/m²), got {gsm!r}")
    x = np.zeros(vocab.size)
    x[vocab.types.index(tag["type"])] = 1.0
    for fibre, frac in comp.items():
        x[len(vocab.types) + vocab.fibres.index(fibre)] = frac
    x[-1] = np.log(gsm / DENSITY_REF_GSM)
    return x


def stretch_targets(stretch: Float[np.ndarray, "n 6"], density_gsm: Float[np.ndarray, " n"]):
    """Regression targets: [log(α/ρ) (ρ in kg/m²) for warp, weft, bias; β warp, weft, bias]."""
    rho = 1e-3 * np.asarray(density_gsm, float)[:, None]
    return np.concatenate([np.log(stretch[:, :3] / rho), stretch[:, 3:]], 1)


class StretchKNN:
    """k-nearest-neighbour regression of stretching parameters from tags (seed 001 §6.1).

    Targets are log(α/ρ) and β, standardised per column before averaging neighbours.
    """

    def __init__(self, k: int = 50):
        self.k = int(k)
        self.vocab: TagVocab | None = None
        self._model = None
        self._targets = None
        self._mean = self._std = None

    def fit(self, catalogue: Catalogue) -> "StretchKNN":
        """Fit on all fabrics of ``catalogue`` (vocabulary taken from it)."""
        from sklearn.neighbors import KNeighborsRegressor

        if len(catalogue) < self.k:
            raise TagError(f"catalogue ({catalogue.source}) has {len(catalogue)} fabrics, fewer than k={self.k}")
        self.vocab = TagVocab.from_catalogue(catalogue)
        x = np.stack([encode_tag(t, self.vocab) for t in catalogue.tags])
        y = stretch_targets(catalogue.stretch, np.array([t["density_gsm"] for t in catalogue.tags]))
        self._mean, self._std = y.mean(0), np.maximum(y.std(0), 1e-12)
        self._targets = y
        self._model = KNeighborsRegressor(n_neighbors=self.k).fit(x, (y - self._mean) / self._std)
        return self

    def predict(self, tag: dict) -> dict:
        """Stretching parameters (SI, ``STRETCH_KEYS``) for one tag, with neighbour spread.

        Returns ``{key: value, ..., "spread": {key: s}}`` where s is the standard deviation
        over the k neighbours of log(α/ρ) for α keys (a multiplicative, dimensionless
        spread) and of β for β keys.
        """
        if self._model is None:
            raise TagError("StretchKNN.predict called before fit")
        x = encode_tag(tag, self.vocab)[None]
        mean = self._model.predict(x)[0] * self._std + self._mean
        nbr = self._model.kneighbors(x, return_distance=False)[0]
        spread = self._targets[nbr].std(0)
        rho = 1e-3 * float(tag["density_gsm"])
        vals = np.concatenate([rho * np.exp(mean[:3]), mean[3:]])
        out = {k: float(v) for k, v in zip(STRETCH_KEYS, vals)}
        out["spread"] = {k: float(s) for k, s in zip(STRETCH_KEYS, spread)}
        return out

    def cross_validate(self, catalogue: Catalogue, folds: int = 10, seed: int = 0) -> list[dict]:
        """K-fold R² of the standardised targets (uniform average over the 6), as seed 001 Table 1.

        Returns one dict per fold: ``fold``, ``train_r2``, ``val_r2`` and ``constant_val_r2``
        (the R² of predicting the training mean, the baseline a useful model must beat).
        The vocabulary is that of the whole catalogue (a fold may miss a rare type).
        """
        from sklearn.metrics import r2_score
        from sklearn.model_selection import KFold
        from sklearn.neighbors import KNeighborsRegressor

        vocab = TagVocab.from_catalogue(catalogue)
        x = np.stack([encode_tag(t, vocab) for t in catalogue.tags])
        y = stretch_targets(catalogue.stretch, np.array([t["density_gsm"] for t in catalogue.tags]))
        y = (y - y.mean(0)) / np.maximum(y.std(0), 1e-12)
        out = []
        for i, (tr, va) in enumerate(KFold(folds, shuffle=True, random_state=seed).split(x), start=1):
            m = KNeighborsRegressor(n_neighbors=self.k).fit(x[tr], y[tr])
            const = np.broadcast_to(y[tr].mean(0, keepdims=True), y[va].shape)
            out.append({"fold": i, "train_r2": float(r2_score(y[tr], m.predict(x[tr]))),
                        "val_r2": float(r2_score(y[va], m.predict(x[va]))),
                        "constant_val_r2": float(r2_score(y[va], const))})
        return out


# --- SYNTHETIC catalogue -------------------------------------------------------------------

FIBRES = ("Cotton", "Polyester", "Nylon", "Viscose rayon", "Wool", "Silk", "Linen",
          "Spandex / Elastane", "Acrylic", "Lyocell")

# Effect of a unit fibre fraction on log α (warp, weft, bias) and on log(1 + β).
_FIBRE_EFFECT = {
    "Cotton": ((0.0, 0.0, 0.0), 0.0),
    "Polyester": ((0.3, 0.3, 0.2), -0.1),
    "Nylon": ((0.2, 0.2, 0.1), 0.1),
    "Viscose rayon": ((-0.3, -0.3, -0.2), 0.1),
    "Wool": ((-0.4, -0.4, -0.3), 0.3),
    "Silk": ((0.1, 0.0, -0.2), 0.0),
    "Linen": ((0.6, 0.5, 0.3), -0.3),
    "Spandex / Elastane": ((-4.0, -8.0, -5.0), 8.0),
    "Acrylic": ((-0.3, -0.2, -0.2), 0.2),
    "Lyocell": ((-0.1, -0.1, 0.0), 0.0),
}

# (category, subcategory, type, median gsm, α warp/weft/bias at median gsm (N/m), β, main fibres,
#  probability of a spandex addition)
_TYPES = (
    ("Woven", "Plain", "Poplin", 110, (500, 320, 60), 2.0, ("Cotton", "Polyester", "Nylon"), 0.15),
    ("Woven", "Plain", "Chiffon", 60, (150, 120, 15), 3.0, ("Polyester", "Silk", "Nylon"), 0.05),
    ("Woven", "Plain", "Crepe / CDC", 90, (200, 150, 25), 4.0, ("Polyester", "Silk", "Viscose rayon"), 0.2),
    ("Woven", "Plain", "Chambray / Oxford", 160, (700, 450, 80), 2.0, ("Cotton", "Linen"), 0.1),
    ("Woven", "Plain", "Voile", 70, (250, 200, 25), 2.5, ("Cotton", "Polyester"), 0.05),
    ("Woven", "Plain", "Taffeta", 100, (800, 600, 120), 1.5, ("Polyester", "Nylon", "Silk"), 0.02),
    ("Woven", "Plain", "Canvas", 330, (1200, 900, 180), 1.0, ("Cotton", "Linen", "Polyester"), 0.02),
    ("Woven", "Twill", "Denim", 370, (1000, 500, 100), 2.0, ("Cotton",), 0.35),
    ("Woven", "Twill", "Gabardine", 230, (800, 500, 90), 2.0, ("Wool", "Polyester", "Cotton"), 0.15),
    ("Woven", "Twill", "Drill", 260, (900, 550, 110), 1.5, ("Cotton", "Polyester"), 0.1),
    ("Woven", "Satin", "Satin", 120, (450, 250, 40), 3.0, ("Polyester", "Silk", "Viscose rayon"), 0.2),
    ("Woven", "Satin", "Charmeuse", 90, (300, 180, 30), 3.5, ("Silk", "Polyester"), 0.1),
    ("Woven", "Dobby", "Dobby", 150, (550, 380, 70), 2.5, ("Cotton", "Polyester", "Viscose rayon"), 0.15),
    ("Woven", "Jacquard", "Jacquard", 250, (650, 450, 100), 2.5, ("Polyester", "Cotton", "Viscose rayon"), 0.1),
    ("Knit", "Single", "Jersey", 160, (60, 30, 25), 8.0, ("Cotton", "Viscose rayon", "Lyocell", "Polyester"), 0.5),
    ("Knit", "Single", "Rib", 220, (50, 15, 20), 10.0, ("Cotton", "Viscose rayon", "Polyester"), 0.6),
    ("Knit", "Double", "Ponte", 280, (120, 70, 50), 6.0, ("Polyester", "Viscose rayon", "Nylon"), 0.7),
    ("Knit", "Double", "Interlock", 200, (90, 50, 35), 6.0, ("Cotton", "Polyester"), 0.3),
    ("Knit", "Pile", "Fleece", 300, (100, 60, 40), 5.0, ("Polyester", "Cotton", "Acrylic"), 0.1),
    ("Knit", "Pile", "French terry", 260, (110, 55, 40), 5.0, ("Cotton", "Polyester"), 0.2),
    ("Knit", "Texture", "Pique", 200, (140, 70, 50), 4.0, ("Cotton", "Polyester"), 0.2),
    ("Knit", "Mesh", "Mesh", 90, (40, 30, 15), 7.0, ("Polyester", "Nylon"), 0.3),
)


def synthetic_catalogue(n: int, seed: int = 0) -> Catalogue:
    """A SYNTHETIC tag catalogue of ``n`` invented fabrics — not measurements of real fabrics.

    Drapejax has no real tag catalogue (seed 001's 5K-DATA from VMOD is not public), so this
    generator stands in for one to exercise and benchmark the regression. 22 fabric types in
    Woven/Knit categories and 10 fibres; each fabric draws a type, a composition (1–2 main
    fibres from the type's list, plus elastane with a type-specific probability) and a
    log-normal density around the type's median. Stretching parameters are
    log α = type base + Σ fibre fraction × fibre effect + 0.6·log(gsm / type median) + noise
    (noise 0.35 in log α, 0.3 in log(1 + β), correlated across directions), so tags explain
    a good part but not all of the variance, like seed 001 Table 1.

    The returned ``Catalogue.source`` starts with "SYNTHETIC" and fabric ids with "SYN-".
    """
    rng = np.random.default_rng(seed)
    tags, stretch = [], []
    corr = np.full((6, 6), 0.5)
    np.fill_diagonal(corr, 1.0)
    corr[:3, 3:] = corr[3:, :3] = -0.2
    noise_ch = np.linalg.cholesky(corr * np.outer([0.35] * 3 + [0.3] * 3, [0.35] * 3 + [0.3] * 3))
    for _ in range(n):
        cat, sub, typ, gsm0, alpha0, beta0, mains, p_spandex = _TYPES[rng.integers(len(_TYPES))]
        comp = {str(rng.choice(mains)): 1.0}
        if rng.random() < 0.4:
            other = str(rng.choice([f for f in FIBRES if f not in comp and f != "Spandex / Elastane"]))
            share = round(float(rng.uniform(0.2, 0.5)), 2)
            comp = {next(iter(comp)): round(1.0 - share, 2), other: share}
        if rng.random() < p_spandex:
            sp = round(float(rng.uniform(0.02, 0.12 if cat == "Knit" else 0.05)), 2)
            comp = {k: round(v * (1.0 - sp), 2) for k, v in comp.items()}
            comp["Spandex / Elastane"] = round(1.0 - sum(comp.values()), 2)
        gsm = float(np.round(gsm0 * np.exp(0.3 * rng.standard_normal()), 0))
        la = np.log(alpha0) + 0.6 * np.log(gsm / gsm0)
        lb = np.log1p(beta0)
        for fibre, frac in comp.items():
            eff_a, eff_b = _FIBRE_EFFECT[fibre]
            la = la + frac * np.asarray(eff_a)
            lb = lb + frac * eff_b
        eps = noise_ch @ rng.standard_normal(6)
        stretch.append(np.concatenate([np.exp(la + eps[:3]), np.expm1(lb + eps[3:])]))
        tags.append({"category": cat, "subcategory": sub, "type": typ, "composition": comp,
                     "density_gsm": gsm})
    ids = tuple(f"SYN-{i:06d}" for i in range(n))
    source = (f"SYNTHETIC catalogue (drapejax.inverse.tags.synthetic_catalogue(n={n}, seed={seed})): "
              f"invented fabrics, not measurements")
    return Catalogue(ids, tuple(tags), np.asarray(stretch, float), source)


__all__ = ["Catalogue", "TagVocab", "TagError", "StretchKNN", "CATALOGUE_COLUMNS", "FIBRES",
           "load_catalogue", "save_catalogue", "encode_tag", "parse_composition",
           "format_composition", "stretch_targets", "synthetic_catalogue"]
