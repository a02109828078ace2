"""How consistently an inverse model reads the real scans, which carry no ground truth.

    python -m experiments.real_consistency [CHECKPOINT ...] [--turns 10 40] [--out rows.jsonl]

Each checkpoint (default: the two packaged ones, 2DS and 3DH) estimates every capture in
../shared/data/real_cusick with the warp angle unknown, as ``drapejax estimate --no-refine`` does.
Reported per model, for the overall stiffness (mean over warp/weft/bias of log k1/ρ):

- ``between_fabric_share``: the fraction of its variance over the 48 captures that the fabric
  explains (one-way ANOVA R²). The captures are 13 fabrics, several specimens and drops each: a
  model that reads stiffness and not drop-to-drop accidents scores near 1.
- ``turn_change``: the largest change of log k1/ρ (per direction, averaged over captures) when
  the scan is turned about the vertical by each of ``--turns`` degrees before estimation.
  The true parameters do not change, so this is pure sensitivity to the in-plane pose.
- ``per_fabric``: the mean and spread over each fabric's captures; and how many captures had an
  estimate outside the model's training range (clipped and named by ``estimate_no_refine``).

Every estimate reads the scan mesh (the stored top views are dropped), so both models see the same
input, turned or not.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
from pathlib import Path

import numpy as np

from drapejax.inverse.estimate import DEFAULT_CHECKPOINT, DIRECTIONS, SCAN_CHECKPOINT, InverseModel
from drapejax.io import load_measurement

if __package__:  # python -m experiments.real_consistency
    from .common import emit
else:  # python experiments/real_consistency.py
    from common import emit

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def log_k1_per_density(out: dict, density: float | None) -> np.ndarray:
    """log k1/ρ (m³/s²) per direction of an ``estimate_no_refine`` result."""
    p = out["params"]
    if density is None:
        return np.log([p[f"bend_k1_{d}_per_density"] for d in DIRECTIONS])
    return np.log([p[f"bend_k1_{d}"] / density for d in DIRECTIONS])


def turned(m, deg: float):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    v = np.asarray(m.scan_vertices, float) @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return dataclasses.replace(m, scan_vertices=v, silhouette=None, height=None)


def between_share(v: np.ndarray, group: np.ndarray) -> float:
    mean = np.array([v[group == g].mean() for g in group])
    return float(1.0 - ((v - mean) ** 2).sum() / ((v - v.mean()) ** 2).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("checkpoints", nargs="*", type=Path, default=[DEFAULT_CHECKPOINT, SCAN_CHECKPOINT])
    ap.add_argument("--turns", nargs="*", type=float, default=[10.0, 40.0])
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    folders = sorted(d for d in (DATA / "real_cusick").iterdir() if d.is_dir())
    fabric = np.array([int(re.match(r"bdp_f(\d+)_", d.name).group(1)) for d in folders])
    captures = [load_measurement(d) for d in folders]
    for path in a.checkpoints:
        model = InverseModel.load(path)
        y, outside, change = [], 0, []
        for m in captures:
            out = model.estimate_no_refine(turned(m, 0.0))
            y.append(log_k1_per_density(out, m.areal_density_kg_m2))
            outside += bool(out["outside_training_range"])
            change.append([np.abs(log_k1_per_density(model.estimate_no_refine(turned(m, t)), m.areal_density_kg_m2)
                                  - y[-1]) for t in a.turns])
        y = np.array(y)
        overall = y.mean(axis=1)
        emit({"checkpoint": str(path), "method": model.method, "captures": len(captures),
              "between_fabric_share": between_share(overall, fabric),
              "between_fabric_share_per_direction": [between_share(y[:, i], fabric) for i in range(3)],
              "turn_degrees": a.turns, "turn_change_log_k1": np.max(np.mean(change, axis=0), axis=0).tolist(),
              "captures_outside_training_range": outside,
              "per_fabric": {int(f): {"mean_log_k1_per_density": float(overall[fabric == f].mean()),
                                      "std": float(overall[fabric == f].std()), "captures": int((fabric == f).sum())}
                             for f in np.unique(fabric)}}, a.out)


if __name__ == "__main__":
    main()
