"""Noise floor of the drape comparison metrics on the real Cusick scans.

For every metric in ``drapejax.observe.metrics`` this compares (a) the same specimen dropped
again (``sample_1_capture_1`` vs ``sample_1_capture_3``), (b) different specimens of one
fabric, and, for scale, (c) specimens of different fabrics. A simulation that matches a
measurement better than (a) is over-fitted to drop noise; one that misses by more than (b)
has not caught the fabric. The warp direction of the scans was not recorded, so every
orientation-dependent metric searches over rotation about the disc axis and over the mirror
image. Prints a JSON summary (median per group, per-fabric medians) and a table of DC and
fold counts per fabric; ``--pairs`` adds every pair's metrics (``"pairs"`` per group, with the two
folder names and the fabric) for quantiles other than the median. Runs in a few minutes on two
CPU cores.

Usage: python -m experiments.noise_floor [--data ../shared/data/real_cusick] [--out summary.json] [--pairs]
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from drapejax.io import load_measurement
from drapejax.observe import (
    align_rotation_z,
    aligned_iou,
    describe,
    drape_coefficient,
    iou,
    mean_relative_curvature_difference,
    mean_vertex_displacement_mm,
    relative_curvature_level_difference,
    rim_profile,
    rotate_about_axis,
    scan_distance_mm,
    silhouette,
    spectral_distance,
)

NAME = re.compile(r"bdp_f(\d+)_sample_(\d+)_capture_(\d+)")


def load_all(data: Path) -> dict:
    """Every folder's measurement, parsed name, descriptors and rim profile."""
    out = {}
    for folder in sorted(p for p in data.iterdir() if NAME.fullmatch(p.name)):
        fabric, sample, capture = map(int, NAME.fullmatch(folder.name).groups())
        m = load_measurement(folder)
        v, f = np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces)
        out[folder.name] = dict(fabric=fabric, sample=sample, capture=capture, m=m, v=v, f=f,
                                desc=describe(m), profile=rim_profile(m.silhouette, m.silhouette_extent_m),
                                dc_render=drape_coefficient(silhouette(v, f)))
    return out


def pairs(items: dict) -> dict[str, list[tuple[str, str]]]:
    by_fabric = defaultdict(list)
    for name, it in items.items():
        by_fabric[it["fabric"]].append(name)
    redrop, specimens, fabrics = [], [], []
    for names in by_fabric.values():
        for a, b in itertools.combinations(sorted(names), 2):
            same_sample = items[a]["sample"] == items[b]["sample"]
            (redrop if same_sample else specimens).append((a, b))
    firsts = [sorted(n)[0] for _, n in sorted(by_fabric.items())]
    fabrics = list(zip(firsts, firsts[1:] + firsts[:1]))
    return {"redrop": redrop, "specimen": specimens, "fabric": fabrics}


def compare(a: dict, b: dict) -> dict:
    """All metrics between two measurements (b is the reference)."""
    score, angle, mirrored = aligned_iou(b["m"].silhouette, a["m"].silhouette, mirror=True)
    rot, mir = align_rotation_z(a["v"], a["f"], b["v"], b["f"], mirror=True)
    va = rotate_about_axis(a["v"], rot, mirror=mir)
    return {
        "iou_unaligned": iou(a["m"].silhouette, b["m"].silhouette),
        "iou_aligned": score,
        "iou_mirrored": float(mirrored),
        "dc_abs_diff": abs(a["desc"]["dc"] - b["desc"]["dc"]),
        "folds_abs_diff": float(abs(a["desc"]["folds"] - b["desc"]["folds"])),
        "spectral_distance_mm": spectral_distance(a["profile"], b["profile"]),
        "scan_distance_mm": scan_distance_mm(va, a["f"], b["v"], b["f"], align_rotation=False),
        "scan_distance_unaligned_mm": scan_distance_mm(a["v"], a["f"], b["v"], b["f"], align_rotation=False),
        "scan_mirrored": float(mir),
        "vertex_displacement_mm": mean_vertex_displacement_mm(va, a["f"], b["v"], b["f"], align_rotation=False),
        "vertex_displacement_template_index_mm": mean_vertex_displacement_mm(
            a["v"], a["f"], b["v"], b["f"], correspondence=True, mirror=True),
        "curvature_pointwise_rel": mean_relative_curvature_difference(va, a["f"], b["v"], b["f"],
                                                                      align_rotation=False),
        "curvature_level_rel": relative_curvature_level_difference(a["v"], a["f"], b["v"], b["f"]),
    }


def summarise(rows: list[tuple[int, dict]]) -> dict:
    keys = rows[0][1].keys()
    per_fabric = defaultdict(list)
    for fabric, r in rows:
        per_fabric[fabric].append(r)
    return {
        "n_pairs": len(rows),
        "median": {k: float(np.median([r[k] for _, r in rows])) for k in keys},
        "p90": {k: float(np.percentile([r[k] for _, r in rows], 90)) for k in keys},
        "per_fabric_median": {f"f{fab:02d}": {k: round(float(np.median([r[k] for r in rs])), 4) for k in keys}
                              for fab, rs in sorted(per_fabric.items())},
    }


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/real_cusick")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--pairs", action="store_true", help="also record every pair's metrics (per group)")
    args = ap.parse_args()
    t0 = time.time()
    items = load_all(args.data)
    groups = pairs(items)
    summary = {}
    for group, plist in groups.items():
        rows = [(items[a]["fabric"], compare(items[a], items[b])) for a, b in plist]
        summary[group] = summarise(rows)
        if args.pairs:
            summary[group]["pairs"] = [{"a": a, "b": b, "fabric": fab, **r} for (a, b), (fab, r) in zip(plist, rows)]
    by_fabric = defaultdict(list)
    for it in items.values():
        by_fabric[it["fabric"]].append(it)
    table = {}
    for fab, its in sorted(by_fabric.items()):
        dc = np.array([it["desc"]["dc"] for it in its])
        folds = np.array([it["desc"]["folds"] for it in its])
        table[f"f{fab:02d}"] = {"n": len(its), "dc_mean": round(float(dc.mean()), 3),
                                "dc_spread": round(float(dc.max() - dc.min()), 3),
                                "folds_mean": round(float(folds.mean()), 2),
                                "folds_min": int(folds.min()), "folds_max": int(folds.max())}
    bias = np.array([it["desc"]["dc"] - it["dc_render"] for it in items.values()])
    summary["dc_stored_minus_rendered"] = {"mean": float(bias.mean()), "min": float(bias.min()),
                                           "max": float(bias.max())}
    summary["per_fabric_dc_folds"] = table
    summary["seconds"] = round(time.time() - t0, 1)
    print(json.dumps({k: ({g: v for g, v in s.items() if g != "pairs"} if isinstance(s, dict) else s)
                      for k, s in summary.items()}, indent=1))
    print("\nfabric   n   DC mean  DC spread  folds mean  folds range")
    for fab, r in table.items():
        print(f"{fab:6s} {r['n']:3d}   {r['dc_mean']:.3f}    {r['dc_spread']:.3f}      {r['folds_mean']:5.2f}"
              f"       {r['folds_min']}-{r['folds_max']}")
    print("\nmedians            " + "  ".join(f"{g:>9s}" for g in groups))
    for k in summary["redrop"]["median"]:
        print(f"{k:38s}" + "  ".join(f"{summary[g]['median'][k]:9.4f}" for g in groups))
    if args.out:
        args.out.write_text(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    main()
