"""How precisely can one simulated Cusick drape pin down k1? Drop-to-drop noise vs sensitivity.

Drops the "mid" example fabric with K drop seeds, and two variants (k1 and k2 of every
direction ×2; warp ×1.5 with weft ÷1.5), and measures on each rest shape the observables
``drapejax.refine`` fits: drape coefficient, fold depth (rms of rim harmonics 3..12), mean hem
height, mean heights on the rings ``refine.RING_RADII_M``, the warp-aligned second harmonic
(``warp_anisotropy``) and the fold count. Prints one JSON object: per variant the mean and
standard deviation over the seeds that reached rest, the sensitivity of each feature to log k1
(overall) and to log(k1_warp/k1_weft), and the implied single-capture precision of those two
quantities, std / |sensitivity|, feature by feature and combined as if the features were
independent (an optimistic bound).

    python -m experiments.redrop_noise                  # 20 mm, 8 seeds: about 5 minutes on 2 cores
    python -m experiments.redrop_noise --spacing-mm 15 --seeds 12
"""

from __future__ import annotations

import argparse
import json
import math

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe, refine  # noqa: E402
from drapejax.material import example_params, from_log_theta  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import drape, quick_config  # noqa: E402

VARIANTS = {"mid": (1.0, 1.0, 1.0), "all_x2": (2.0, 2.0, 2.0), "warp_x1.5_weft_/1.5": (1.5, 1 / 1.5, 1.0)}
RINGS = tuple(f"ring{round(r * 1000)}mm_m" for r in refine.RING_RADII_M)
FEATURES = ("dc", "fold_rms_m", "hem_m", *RINGS, "aniso_m", "fold_count")


def features(x: np.ndarray, mesh) -> dict[str, float]:
    """The observables of ``drapejax.refine`` (its own feature functions) on one rest shape."""
    faces, info = np.asarray(mesh.faces), mesh.info
    sil = observe.silhouette(x, faces, n=256, extent_m=refine.EXTENT_M)
    height = observe.height_map(x, faces, n=256, extent_m=refine.EXTENT_M)
    dc, amp, hem = refine.hard_features(sil, refine.EXTENT_M, height, refine.EXTENT_M,
                                        info.specimen_radius_m, info.disk_radius_m)
    profile = observe.rim_profile(sil, refine.EXTENT_M, n_angles=refine.N_ANGLES)
    rings = refine.ring_heights(height, refine.EXTENT_M)
    return {"dc": float(dc), "fold_rms_m": refine.fold_rms(amp), "hem_m": hem,
            **{k: float(v) for k, v in zip(RINGS, rings)},
            "aniso_m": refine.warp_anisotropy(profile, 0.0), "fold_count": float(observe.fold_count(profile))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spacing-mm", type=float, default=20.0)
    ap.add_argument("--seeds", type=int, default=8)
    a = ap.parse_args()
    mesh = cusick_mesh(a.spacing_mm / 1000)
    run = jax.jit(lambda p, s: drape(mesh, p, s, config=quick_config()))
    base = example_params("mid")
    out = {"spacing_mm": a.spacing_mm, "seeds": a.seeds, "solver": "quick_config", "variants": {}}
    rows = {}
    for name, s in VARIANTS.items():
        res = [run(from_log_theta(base, jnp.log(jnp.asarray(s))), seed) for seed in range(a.seeds)]
        status = [int(r.status) for r in res]
        feats = [features(np.asarray(r.x), mesh) for r, st in zip(res, status) if st == 0]
        rows[name] = {f: np.array([v[f] for v in feats]) for f in FEATURES}
        out["variants"][name] = {"status": status, **{f: {"mean": float(rows[name][f].mean()),
                                                          "std": float(rows[name][f].std(ddof=1)),
                                                          "values": rows[name][f].round(5).tolist()}
                                                      for f in FEATURES}}
    mid, up, split = rows["mid"], rows["all_x2"], rows["warp_x1.5_weft_/1.5"]
    d_overall, d_split = math.log(2.0), 2 * math.log(1.5)
    prec = {}
    for target, other, dlog in (("log_k1", up, d_overall), ("log_k1_warp_over_weft", split, d_split)):
        per, info = {}, 0.0
        for f in FEATURES:
            sens = (other[f].mean() - mid[f].mean()) / dlog
            noise = math.sqrt(0.5 * (mid[f].var(ddof=1) + other[f].var(ddof=1)))
            sigma = noise / abs(sens) if sens else math.inf
            per[f] = {"sensitivity_per_log": float(sens), "noise": noise, "sigma_log": sigma,
                      "sigma_pct": 100 * (math.exp(sigma) - 1) if sigma < 20 else None}
            info += (sens / noise) ** 2 if noise > 0 else 0.0
        combined = 1 / math.sqrt(info) if info > 0 else math.inf
        prec[target] = {"per_feature": per, "combined_sigma_log": combined,
                        "combined_sigma_pct": 100 * (math.exp(combined) - 1) if combined < 20 else None}
    out["single_capture_precision"] = prec
    print(json.dumps(out))


if __name__ == "__main__":
    main()
