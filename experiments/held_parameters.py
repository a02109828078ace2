"""Which parameter a drape fit holds fixed moves the drape? Virtual-lab captures of an example
fabric, scored against fresh drops of the true fabric and of the true fabric with one group of its
fields replaced by the network's estimate from the first capture.

A drape fit moves k1 only; every other field comes from the tag or the network. When the baseline
of ``diagnose`` cannot reach its own clean captures, this says which held field is to blame: each
row is the selection misfit (½χ², ``diagnose.select.selection_misfits``: the skirt's height
profile, DC, first and second harmonics, fold depth) of ``--drops`` fresh drops of one fabric,
each scored on the held-out captures (seeds ``--first-seed`` + 1, + 2) and averaged, as
``diagnose``'s expected misfit is. Groups: ``truth``, ``network`` (every field but the density and
k1 from the network), ``stretch_alpha``, ``stretch_beta``, ``bend_k2`` (that group alone from the
network), and ``k1 W,F,B`` factors (``--k1-factors``) applied to the truth.

    python -m experiments.held_parameters --fabric light --k1-factors 1.164,1.115,0.823

One JSON line per group: {"fabric", "group", "misfit", "per_drop", "dc", "captures_dc"}.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from drapejax.diagnose import initial_params  # noqa: E402
from drapejax.diagnose.select import selection_misfits  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.material import DIRECTIONS, PARAM_KEYS, FabricParams, example_params  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.refine import measured_targets  # noqa: E402
from drapejax.virtual_lab import make_measurement, simulate_with_effects  # noqa: E402

if __package__:  # python -m experiments.held_parameters
    from .common import emit
else:  # python experiments/held_parameters.py
    from common import emit

GROUPS = ("stretch_alpha", "stretch_beta", "bend_k2")


def with_fields(p: FabricParams, q: FabricParams, prefix: str | None) -> FabricParams:
    """``p`` with the fields of ``q`` whose names start with ``prefix`` (None: every field but the
    density and k1)."""
    take = (lambda k: k.startswith(prefix)) if prefix else (lambda k: k != "density" and not k.startswith("bend_k1"))
    return FabricParams(**{k: getattr(q if take(k) else p, k) for k in PARAM_KEYS})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fabric", default="light", help="an example fabric")
    ap.add_argument("--first-seed", type=int, default=1, help="drop seed of the first capture (the others follow)")
    ap.add_argument("--drops", type=int, default=3, help="fresh drops per group (seeds 2000, 2001, ...)")
    ap.add_argument("--spacing-mm", type=float, default=20.0)
    ap.add_argument("--rim-mm", type=float, default=3.0)
    ap.add_argument("--k1-factors", default=None, help="W,F,B: also score the truth with its k1 times these")
    ap.add_argument("--out", type=Path, default=None, help="append the JSON lines here too")
    a = ap.parse_args()
    spacing, rim = a.spacing_mm / 1e3, (a.rim_mm / 1e3 if a.rim_mm > 0 else None)
    truth = example_params(a.fabric)
    with tempfile.TemporaryDirectory() as tmp:
        folders = [make_measurement(Path(tmp) / f"capture_{i}", params=truth, spacing_m=spacing, rim_spacing_m=rim,
                                    seed=a.first_seed + i) for i in range(3)]
        ms = [load_measurement(f) for f in folders]
    network = initial_params(ms[0])
    mesh = cusick_mesh(spacing, rim_spacing_m=rim)
    held = ms[1:]
    misfits = selection_misfits(held, mesh)
    fabrics = {"truth": truth, "network": with_fields(truth, network, None)}
    fabrics.update({g: with_fields(truth, network, g) for g in GROUPS})
    if a.k1_factors:
        f = [float(v) for v in a.k1_factors.split(",")]
        fabrics[f"k1 {a.k1_factors}"] = FabricParams(**{k: getattr(truth, k) * (f[DIRECTIONS.index(k.split("_")[-1])]
                                                                               if k.startswith("bend_k1") else 1.0)
                                                          for k in PARAM_KEYS})
    captures_dc = [round(measured_targets(m).dc, 4) for m in held]
    for group, p in fabrics.items():
        per, dc = [], []
        for s in range(2000, 2000 + a.drops):
            x = simulate_with_effects(p, {}, spacing_m=spacing, rim_spacing_m=rim, seed=s)[0]
            per.append(float(np.mean([mf.loss(x) for mf in misfits])))
            dc.append(round(float(misfits[0].hard(x)[0]), 4))  # the feature vector starts with the DC
        emit({"fabric": a.fabric, "group": group, "misfit": float(np.mean(per)), "per_drop": per, "dc": dc,
              "captures_dc": captures_dc,
              "stretch_alpha": [float(getattr(p, f"stretch_alpha_{d}")) for d in DIRECTIONS]}, a.out)


if __name__ == "__main__":
    main()
