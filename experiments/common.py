"""Helpers that several experiments share: JSON-line output, the real scans' grouping, the
virtual lab's hidden effects and the options that name them, rest-shape observables and the
inverse-map datasets.

Not an entry point. The experiments import it as ``experiments.common`` when run as
``python -m experiments.NAME`` and as ``common`` when run as ``python experiments/NAME.py``; it
imports nothing from the experiments themselves.
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from drapejax import compile_cache, observe, refine
from drapejax.effects import REGISTRY
from drapejax.inverse import estimate as est
from drapejax.inverse.dataset import OBSERVATION_SETTINGS, load
from drapejax.inverse.prior import read_fabric_table
from drapejax.io import BENCH_FIELDS, CUT_ANGLES_DEG
from drapejax.material import G, PARAM_KEYS, FabricParams, bending_length, example_params
from drapejax.mesh import CUSICK_RADIUS_M, DISK_RADIUS_M

compile_cache.enable()  # a repeated study or sweep loads the drape programs its first run compiled

# --- fabrics of the 618-fabric table ------------------------------------------------------------

TABLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference" / "fabrics_618_bending.csv"
PICKS = ("softest", "lightest", "q25", "median", "q90")
EXAMPLES = ("light", "mid", "heavy")


def pick_fabrics(path: Path, picks=PICKS) -> dict[str, tuple[int, FabricParams, float]]:
    """name -> (row, params, overall bending length m) for each pick of the fabric table."""
    rho, k1, k2 = read_fabric_table(path)
    length = (np.prod(k1, axis=1) ** (1 / 3) / (rho * G)) ** (1 / 3)
    rows = {"softest": int(np.argmin(length)), "lightest": int(np.argmin(rho)), "stiffest": int(np.argmax(length)),
            "median": int(np.argmin(np.abs(length - np.median(length))))}
    out = {}
    for name in picks:
        if name in EXAMPLES:  # an embedded example fabric, not a table row
            q = example_params(name)
            out[name] = (-1, q, float(bending_length(q, "mean")))
            continue
        quantile = re.fullmatch(r"q(\d\d)", name)
        if quantile:  # qNN: the row nearest the NN % quantile of the overall bending length
            rows[name] = int(np.argmin(np.abs(length - np.quantile(length, int(quantile.group(1)) / 100))))
        if name not in rows:
            raise ValueError(f"fabric pick {name!r}: expected softest, lightest, stiffest, median, qNN (a percentile "
                             f"such as q25) or one of {', '.join(EXAMPLES)}")
        i = rows[name]
        p = FabricParams.make(density=rho[i], bend_k1_warp=k1[i, 0], bend_k1_weft=k1[i, 1], bend_k1_bias=k1[i, 2],
                              bend_k2_warp=k2[i, 0], bend_k2_weft=k2[i, 1], bend_k2_bias=k2[i, 2])
        out[name] = (i, p, float(length[i]))
    return out


def prior_softest(n: int, samples: int = 200, seed: int = 0, skip: int = 0
                  ) -> dict[str, tuple[int, FabricParams, float]]:
    """name -> (sample index, params, overall bending length m) for the ``n`` softest of ``samples``
    draws (``seed``) of the inverse map's prior, by overall bending length (k1/(ρ g))^(1/3): the
    fabrics ``tests/test_simulator.py`` drapes on a small mesh, for the default resolution; ``skip``
    leaves out the softest ``skip`` of them (to resume a study)."""
    from drapejax.inverse.prior import default_prior
    p = default_prior().sample(samples, seed)
    length = np.asarray(bending_length(p, "mean"))
    out = {}
    for i in np.argsort(length)[skip:n]:
        q = FabricParams(**{k: getattr(p, k)[i] for k in PARAM_KEYS})
        out[f"prior{int(i)}"] = (int(i), q, float(length[i]))
    return out



# --- JSON lines -------------------------------------------------------------------------------


def emit(row: dict, out: Path | None) -> None:
    """Print ``row`` as one JSON line, and append it to ``out`` when given (survives a kill)."""
    line = json.dumps(row, default=float)
    print(line, flush=True)
    if out is not None:
        with open(out, "a") as f:
            f.write(line + "\n")


def read(path: Path) -> list[dict]:
    """The rows of a file of JSON lines (blank lines skipped)."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


# --- real scans -------------------------------------------------------------------------------


def groups(data: Path, by: str = "fabric") -> dict[str, list[Path]]:
    """Folders grouped by fabric or by specimen (fabric, sample), in (sample, capture) order."""
    out: dict[str, list[tuple[int, int, Path]]] = defaultdict(list)
    for d in data.iterdir():
        m = re.fullmatch(r"bdp_f(\d+)_sample_(\d+)_capture_(\d+)", d.name)
        if m:
            key = f"f{m[1]}" if by == "fabric" else f"f{m[1]}_s{m[2]}"
            out[key].append((int(m[2]), int(m[3]), d))
    return {k: [d for *_, d in sorted(v)] for k, v in sorted(out.items())}


# --- the virtual lab's hidden effects ---------------------------------------------------------

STRENGTHS = {
    "clean": {},
    "off_centre": {"off_centre": [0.02, 0.0]},
    "edge_curl": {"edge_curl": [60.0]},
    "bias_asymmetry": {"bias_asymmetry": [1.0]},
    "plastic_set": {"plastic_set": [40.0]},
    "heavy_hem": {"heavy_hem": [2.0]},
    "self_contact": {"self_contact": [0.004]},
    "heterogeneity": {"heterogeneity": [0.8, 0.0, 0.0, 0.0]},
    "bending_saturation": {"bending_saturation": [1.0]},
    "clamp_hinge": {"clamp_hinge": [1.0]},
    "bending_friction": {"bending_friction": [20.0]},
}
"""Hidden effect strengths: each clearly present (curl radius 17 mm, +45° bias twice as stiff,
crease radius 25 mm, hem band 3x as heavy, 20 mm off-centre, 4 mm thick fabric, rigidity
varying by e^±0.8 across the specimen, 44 % of the bending energy removed at large curvature (θ = 1),
a clamp-edge hinge as compliant as one bending length of fabric, a frictional bending moment
equal to the elastic one at 20 m⁻¹)."""


def parse_hidden(items: list[str], ap: argparse.ArgumentParser) -> dict[str, list[float]]:
    """``name=θ[,θ...]`` items of ``--hidden`` as {name: θ}, each name registered."""
    out = {}
    for item in items:
        name, _, values = item.partition("=")
        if name not in REGISTRY or not values:
            ap.error(f"--hidden {item!r}: expected NAME=THETA with NAME one of {', '.join(REGISTRY)}")
        out[name] = [float(v) for v in values.split(",")]
    return out


def parse_candidates(text: str, ap: argparse.ArgumentParser) -> list[str]:
    """The comma list of ``--candidates``, each registered, at least one."""
    names = [n for n in text.split(",") if n]
    unknown = [n for n in names if n not in REGISTRY]
    if unknown or not names:
        ap.error(f"--candidates: unknown {unknown}; known: {', '.join(REGISTRY)}")
    return names


def parse_bench_tests(flag: str, tokens: list[str], ap: argparse.ArgumentParser) -> list[tuple[str, str]]:
    """``TEST:DIRECTION`` tokens of ``flag`` as (test, direction) pairs of ``io.BENCH_FIELDS`` and
    ``io.CUT_ANGLES_DEG``."""
    tests = [tuple(t.split(":", 1)) for t in tokens]
    if any(len(t) != 2 or t[0] not in BENCH_FIELDS or t[1] not in CUT_ANGLES_DEG for t in tests):
        ap.error(f"{flag} {tokens}: expected TEST:DIRECTION, TEST one of {tuple(BENCH_FIELDS)}, "
                 f"DIRECTION one of {tuple(CUT_ANGLES_DEG)}")
    return tests


def generator(effects: dict) -> tuple[list, np.ndarray]:
    """The hidden generator of a case's captures as a model: (its effect objects, θ = the true
    k1 (log-scales 0 relative to "mid") then the effects' hidden values)."""
    hidden = [REGISTRY[n] for n in effects]
    return hidden, np.concatenate([np.zeros(3)] + [np.asarray(effects[e.name], float) for e in hidden])


# --- observables of a rest shape --------------------------------------------------------------

EXTENT_M = 0.16
"""Half-width of the silhouette ``dc_and_folds`` renders, m."""


def dc_and_folds(x, mesh) -> tuple[float, int]:
    """Drape coefficient and fold count of a rest shape from its 256 px top silhouette."""
    sil = observe.silhouette(np.asarray(x), np.asarray(mesh.faces), n=256, extent_m=EXTENT_M)
    dc = observe.drape_coefficient(sil, EXTENT_M, specimen_radius_m=mesh.info.specimen_radius_m,
                                   disk_radius_m=mesh.info.disk_radius_m)
    return round(float(dc), 4), int(observe.fold_count(observe.rim_profile(sil, EXTENT_M)))


EXTRA_RINGS_M = tuple(np.round(np.arange(0.095, 0.1451, 0.005), 3))
"""Radii of the extended observables' rings of mean height, m (``features(...)["extended"]``)."""


def features(x: np.ndarray, faces: np.ndarray, warp_angle_deg: float = 0.0) -> dict[str, np.ndarray]:
    """Hard observables of a rest state: the library's (``refine``) and the extended ones."""
    sil = observe.silhouette(x, faces, n=256, extent_m=refine.EXTENT_M)
    hm = observe.height_map(x, faces, n=256, extent_m=refine.EXTENT_M)
    prof = observe.rim_profile(sil, refine.EXTENT_M, n_angles=refine.N_ANGLES)
    dc, amp, hem = refine.hard_features(sil, refine.EXTENT_M, hm, refine.EXTENT_M, CUSICK_RADIUS_M, DISK_RADIUS_M)
    rings = refine.ring_heights(hm, refine.EXTENT_M, EXTRA_RINGS_M)
    lib = np.concatenate([[dc, refine.fold_rms(amp)], refine.first_harmonic(prof), [hem],
                          refine.ring_heights(hm, refine.EXTENT_M),
                          [refine.warp_anisotropy(prof, warp_angle_deg), refine.bias_shear(prof, warp_angle_deg)]])
    ext = np.concatenate([[dc], amp, refine.first_harmonic(prof), [hem], rings,
                          [refine.warp_anisotropy(prof, warp_angle_deg), refine.bias_shear(prof, warp_angle_deg)]])
    return {"library": lib, "extended": ext}


LIBRARY_SIGMA = np.array([refine.SIGMA_DC, refine.SIGMA_HARMONIC_M, refine.SIGMA_C1_M, refine.SIGMA_C1_M]
                         + [refine.SIGMA_HEM_M] * (1 + len(refine.RING_RADII_M)) + [refine.SIGMA_H2_M] * 2)
"""The whitening of ``refine.Misfit``'s rows, in the order of ``features(...)["library"]``."""


# --- datasets of the inverse map --------------------------------------------------------------


def drops_per_member(directory: str) -> int:
    """Drops of each prior member in a generated dataset (``dataset.json``; 1 unless recorded)."""
    return json.loads((Path(directory) / "dataset.json").read_text()).get("drops_per_member", 1)


def load_dataset(directory: str, max_samples: int | None, repeats: bool = False) -> dict[str, np.ndarray]:
    """Converged samples (status 0) of a generated dataset, at most ``max_samples``. Raises
    SystemExit for a dataset of repeated drops (``drops_per_member`` > 1) unless ``repeats``: a
    random split would put drops of one member on both of its sides."""
    data = load(directory)
    drops = drops_per_member(directory)
    if drops > 1 and not repeats:
        raise SystemExit(f"{directory}: dataset.json drops_per_member = {drops}: drops of one member would "
                         f"fall on both sides of a split; use it as a test set (inverse_baseline.py --test)")
    ok = np.flatnonzero(data["status"] == 0)[:max_samples]
    return {k: v[ok] for k, v in data.items()}


K1_COLUMNS = [i for i, name in enumerate(est.TARGET_NAMES) if name.startswith("log_k1_")]
"""Columns of the targets that are log k1/ρ (warp, weft, bias)."""


def split(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(validation, training) indices of ``n`` samples: a seeded permutation, ``val_fraction`` held out."""
    perm = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(val_fraction * n)))
    return perm[:n_val], perm[n_val:]


def harmonic_meta(data: dict, phase_harmonics: int) -> dict:
    """The 3DH ``meta`` entries of a dataset: the settings ``InverseModel`` reads back for a scan."""
    ext = float(OBSERVATION_SETTINGS["height"]["extent_m"])
    return {"n_points": int(data["boundary"].shape[1]), "specimen_radius_m": CUSICK_RADIUS_M,
            "source_size": int(data["height"].shape[-1]), "source_extent_m": ext, "ring_inner_m": DISK_RADIUS_M,
            "ring_outer_m": ext, "phase_harmonics": phase_harmonics}


def harmonic_features(data: dict, meta: dict) -> np.ndarray:
    """3DH descriptors (``estimate.harmonic_feature``) of every drape's ``boundary`` and ``height``,
    with the settings in ``meta`` (``harmonic_meta``), as ``InverseModel`` computes them."""
    return np.stack([est.harmonic_feature(b, h, meta["source_extent_m"], specimen_radius_m=meta["specimen_radius_m"],
                                          ring_inner_m=meta["ring_inner_m"], ring_outer_m=meta["ring_outer_m"],
                                          phase_harmonics=meta["phase_harmonics"])
                     for b, h in zip(data["boundary"], data["height"])])
