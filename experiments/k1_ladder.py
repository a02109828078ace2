"""Can a k1-only model mimic a hidden effect over fresh drops? A null k1 ladder against the truth.

For each virtual-lab case (``common.STRENGTHS`` × ``--scale``) this makes the same
captures as ``effect_recovery.py`` ("mid", drop seeds 0, 1, …), drops the hidden generator at
``--seeds`` fresh seeds, and drops the model WITHOUT the effect, in the generator's own family
("mid"), with all three k1 multiplied by 2^(i/4), i = −4…4, at the same seeds. Every capture and
drop is reduced to the observables of ``common.features`` (the library's rows and
the extended ones: twelve rim harmonics and eleven rings of mean height, 95–145 mm).

Each model is scored by its expected misfit: ½χ² of every drop against every capture, averaged,
with the fit's rows (``refine.Misfit``) and with "selection rows": the two fitted rings replaced
by the height profile at ``refine.PROFILE_RADII_M``, each ring over ``refine.SIGMA_PROFILE_M`` (the
library's selection misfit, ``refine.Misfit(profile=True)``). "gain" = best null
ladder point − truth: what an effect can earn over a k1-only model that may pick its k1 freely,
with fold placement averaged out. It also prints the profile rings' drop-to-drop and
capture-to-capture std pooled over the cases run (``refine.SIGMA_PROFILE_M`` is their combination over
the eight scale-1 cases). The raw observables are written with ``--out`` and can be rescored
with ``--load`` (no dropping).

Usage: python -m experiments.k1_ladder [--only edge_curl,bias_asymmetry] [--scale 1] [--seeds 3]
       [--spacing 0.025] [--out raw.jsonl] [--load raw.jsonl ...]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from drapejax import refine
from drapejax.diagnose.select import fresh_drop, effect_problem
from drapejax.io import load_measurement
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import make_measurement

jax.config.update("jax_enable_x64", True)

if __package__:  # python -m experiments.k1_ladder
    from .common import EXTRA_RINGS_M, LIBRARY_SIGMA, STRENGTHS, features, generator, read
else:  # python experiments/k1_ladder.py
    from common import EXTRA_RINGS_M, LIBRARY_SIGMA, STRENGTHS, features, generator, read

FACTORS = tuple(2.0 ** (i / 4) for i in range(-4, 5))
RINGS_AT = 5
"""Index of the first ring height in ``common.features(...)["library"]`` (after DC,
fold depth, first harmonic (x, y) and hem), and of the first profile ring in the selection rows."""
EXTENDED_RINGS_AT = 1 + refine.N_HARMONICS + 2 + 1
"""The same in ``features(...)["extended"]`` (after DC, twelve harmonics, first harmonic, hem)."""


def _feats(x, faces) -> dict:
    return {k: np.asarray(v).tolist() for k, v in features(np.asarray(x), faces).items()}


def _rows(f: dict, selection: bool) -> np.ndarray:
    """Rows of one feature dict in ``common.LIBRARY_SIGMA``'s order; with
    ``selection`` the two fitted rings replaced by the height profile at ``refine.PROFILE_RADII_M``."""
    lib = np.asarray(f["library"])
    if not selection:
        return lib
    ext = np.asarray(f["extended"])
    rings = dict(zip(np.round(EXTRA_RINGS_M, 3), ext[EXTENDED_RINGS_AT:EXTENDED_RINGS_AT + len(EXTRA_RINGS_M)]))
    return np.concatenate([lib[:RINGS_AT], [rings[round(r, 3)] for r in refine.PROFILE_RADII_M],
                           lib[RINGS_AT + len(refine.RING_RADII_M):]])


def _sigma(selection: bool) -> np.ndarray:
    if not selection:
        return LIBRARY_SIGMA
    return np.concatenate([LIBRARY_SIGMA[:RINGS_AT], refine.SIGMA_PROFILE_M,
                           LIBRARY_SIGMA[RINGS_AT + len(refine.RING_RADII_M):]])


def score(drops: list[dict], captures: list[dict], selection: bool) -> float:
    """Mean ½χ² of every drop against every capture."""
    sig = _sigma(selection)
    out = [0.5 * float(np.sum(((_rows(d, selection) - _rows(c, selection)) / sig) ** 2))
           for d in drops for c in captures]
    return float(np.mean(out)) if out else float("inf")


def run_case(case: str, effects: dict, args, work: Path) -> dict:
    truth_p = example_params("mid")
    mesh = cusick_mesh(args.spacing, warp_angle_deg=0.0)
    faces = np.asarray(mesh.faces)
    folders = [make_measurement(work / case / f"capture_{i}", params=truth_p, effects=effects, spacing_m=args.spacing,
                                seed=i) for i in range(args.captures)]
    ms = [load_measurement(f) for f in folders]
    caps = [_feats(m.scan_vertices, np.asarray(m.scan_faces)) for m in ms]
    targets = refine.measured_targets(ms[0])
    seeds = [3000 + i for i in range(args.seeds)]
    hidden, th_truth = generator(effects)
    prob_t = effect_problem(targets, hidden, truth_p, mesh, args.spacing, config=refine.CONTINUATION_CONFIG)
    truth = [_feats(x, faces) for s in seeds if (x := fresh_drop(prob_t, th_truth, s)) is not None]
    prob_n = effect_problem(targets, [], truth_p, mesh, args.spacing, config=refine.CONTINUATION_CONFIG)
    ladder = []
    for f in FACTORS:
        th = np.full(3, math.log(f))
        ladder.append({"factor": f, "drops": [_feats(x, faces) for s in seeds
                                              if (x := fresh_drop(prob_n, th, s)) is not None]})
    return {"case": case, "hidden_values": effects, "captures": caps, "truth": truth, "ladder": ladder}


def profile_noise(rows: list[dict]) -> dict:
    """Drop-to-drop (truth drops) and capture-to-capture std of the profile rings, m, pooled
    over the cases (the measurement behind ``refine.SIGMA_PROFILE_M``)."""
    ring = lambda fs: np.array([_rows(f, True)[RINGS_AT:RINGS_AT + len(refine.PROFILE_RADII_M)] for f in fs])
    pool = lambda key: np.sqrt(np.mean([ring(r[key]).var(0, ddof=1) for r in rows if len(r[key]) > 1], 0))
    drop, cap = pool("truth"), pool("captures")
    return {"radii_m": list(refine.PROFILE_RADII_M), "drop_std_m": drop.tolist(), "capture_std_m": cap.tolist(),
            "combined_m": np.hypot(drop, cap).tolist()}


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        row = {"case": r["case"], "hidden_values": r["hidden_values"]}
        for selection, name in ((False, "fit_rows"), (True, "selection_rows")):
            t = score(r["truth"], r["captures"], selection)
            lad = [score(p["drops"], r["captures"], selection) for p in r["ladder"]]
            i = int(np.argmin(lad))
            row[name] = {"truth": t, "ladder": lad, "best_factor": FACTORS[i], "best_null": lad[i], "gain": lad[i] - t}
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--spacing", type=float, default=0.025)
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--load", type=Path, nargs="*", default=(), help="score saved raw rows instead of dropping")
    ap.add_argument("--out", type=Path, default=None, help="raw rows (JSON lines)")
    args = ap.parse_args()
    if args.load:
        rows = [r for p in args.load for r in read(p)]
    else:
        only = {s.strip() for s in args.only.split(",") if s.strip()}
        work = Path(tempfile.mkdtemp(prefix="k1_ladder_"))
        rows = []
        for case, effects in STRENGTHS.items():
            if only and case not in only:
                continue
            t0 = time.perf_counter()
            r = run_case(case, {k: [args.scale * v for v in th] for k, th in effects.items()}, args, work)
            r["seconds"] = time.perf_counter() - t0
            rows.append(r)
            if args.out is not None:
                with open(args.out, "a") as fh:
                    fh.write(json.dumps(r, default=float) + "\n")
            print(json.dumps({"case": case, "seconds": r["seconds"]}), flush=True)
    print(json.dumps({"profile_noise": profile_noise(rows)}), flush=True)
    for s in summarise(rows):
        print(json.dumps(s, default=float), flush=True)


if __name__ == "__main__":
    main()
