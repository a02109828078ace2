"""Mesh convergence of the Cusick drape on nested meshes, for fabrics across the 618-fabric table.

For each chosen fabric of ``../shared/data/reference/fabrics_618_bending.csv`` (Feng et al. 2022)
and each drop seed, a cascadic drape (the dynamic drop on a rim-graded coarse mesh, then a static
solve on each uniform subdivision, ``solve.drape_multilevel``'s scheme and defaults: the coarse
drop with each term's ``coarse_level()``, the fine solves with ``FINE_CONFIG``) is stopped
at every level
and measured there: drape coefficient, fold count, status, Newton iterations, seconds, and the
scan distance (mean closest-point distance, mm) to the finest level's rest shape. Because the
meshes are nested, each level's spacing is exactly half the previous one, and the level results
give a Richardson estimate of the refinement limit of the seed-mean drape coefficient
(Richardson 1911): with differences d1 = DC2 − DC1 and d2 = DC3 − DC2 the observed order is
p = log2(d1/d2) and the limit DC3 + d2/(2^p − 1) (when d1 and d2 have the same sign; otherwise no
order is observed, nor when p < 0.5, and the finest value is reported with |d2| as its uncertainty).

Fabrics are picked from the table by their overall bending length (k1/(ρ g))^(1/3): the softest,
the lightest, and the rows nearest the 25 %, 50 % and 90 % quantiles. The coarsest level is a fixed
spacing (``--spacing-mm``) or a multiple of each fabric's bending length
(``--coarsest-over-length``): the drop on the coarsest level chooses the fold pattern the finer
levels keep, and a mesh that cannot resolve the fabric's fold wavelength chooses too few folds. One JSON line per
(fabric, seed, level), then one summary line per fabric; ``--figure`` draws the drape coefficient
against the finest spacing with each fabric's Richardson limit (matplotlib, the ``experiments``
extra).

    python -m experiments.mesh_convergence --seeds 0,1,2 --out /tmp/conv.jsonl --figure /tmp/conv.png
    python -m experiments.mesh_convergence --coarsest-over-length 0.75 --levels 3 --max-verts 12000 --seeds 0
    python -m experiments.mesh_convergence --summarize /tmp/conv.jsonl --figure docs/results/mesh_convergence.png
    python -m experiments.mesh_convergence --default 2.5 --seeds 0,1,2,3,4 --fabrics q25,q90  # one level finer
    python -m experiments.mesh_convergence --default 2.5 --polish-coarsest --fabrics softest  # a single-level default
    python -m experiments.mesh_convergence --default auto --seeds 0,1,2,3,4 --fabrics lightest  # simulate's own default
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.energy import coarse_level, default_energies  # noqa: E402
from drapejax.mesh import RIM_RATIO, cusick_hierarchy, nested_cusick_meshes  # noqa: E402
from drapejax.observe.metrics import scan_distance_mm  # noqa: E402
from drapejax.solve import (FINE_CONFIG, STATUS_NAMES, SolverConfig, coarsest_spacing_m, drape, finest_spacing_m,  # noqa: E402
                            polished_status, static_solve)

if __package__:  # python -m experiments.mesh_convergence
    from .common import PICKS, TABLE, dc_and_folds, pick_fabrics, prior_softest
else:  # python experiments/mesh_convergence.py
    from common import PICKS, TABLE, dc_and_folds, pick_fabrics, prior_softest

MIN_ORDER = 0.5
"""Below this observed order the differences are not shrinking: no limit is extrapolated."""


def richardson(dcs: list[float]) -> dict:
    """Refinement limit of a sequence over halving spacings (last three values); without an
    observed order of at least ``MIN_ORDER``, the finest value with the last difference as its
    uncertainty."""
    if len(dcs) < 3:
        return {"limit": dcs[-1], "order": None, "uncertainty": abs(dcs[-1] - dcs[-2]) if len(dcs) > 1 else None}
    d1, d2 = dcs[-2] - dcs[-3], dcs[-1] - dcs[-2]
    if d1 * d2 > 0 and abs(d2) < abs(d1) and np.log2(d1 / d2) >= MIN_ORDER:
        p = float(np.log2(d1 / d2))
        corr = d2 / (2.0 ** p - 1.0)
        return {"limit": dcs[-1] + corr, "order": p, "uncertainty": abs(corr)}
    return {"limit": dcs[-1], "order": None, "uncertainty": abs(d2)}


def run(a) -> list[dict]:
    terms = default_energies("cusick")
    coarse_terms = coarse_level(terms)  # drape_multilevel's levels
    fine_cfg = dataclasses.replace(FINE_CONFIG, force_tol=a.force_tol)
    rows = []
    out = open(a.out, "a") if a.out else None
    fabrics = (prior_softest(a.prior_softest, skip=a.prior_skip) if a.prior_softest
               else pick_fabrics(Path(a.table), a.fabrics.split(",")))
    for name, (row, p, length) in fabrics.items():
        if a.default is not None:  # the hierarchy ``drapejax simulate --spacing-mm`` drapes on
            finest = finest_spacing_m(p) if a.default == "auto" else float(a.default) / 1e3
            meshes, prolongs = cusick_hierarchy(finest, coarsest_spacing_m=coarsest_spacing_m(p))
            h0, levels, rim_ratio = meshes[0].info.spacing_m, len(meshes), RIM_RATIO
        else:
            h0 = a.spacing_mm / 1e3 if a.coarsest_over_length is None else round(a.coarsest_over_length * length, 4)
            levels, rim_ratio = a.levels, a.rim_ratio
            while levels > 1 and a.max_verts and _verts(h0, levels, rim_ratio) > a.max_verts:
                levels -= 1
            meshes, prolongs = nested_cusick_meshes(h0, levels, rim_spacing_m=h0 / rim_ratio)
        coarse = jax.jit(lambda p, s: drape(meshes[0], p, s, terms=coarse_terms, config=SolverConfig()))
        polish = jax.jit(lambda p, x0: static_solve(meshes[0], p, x0, terms=terms, config=fine_cfg))
        statics = [jax.jit(lambda p, x0, m=m: static_solve(m, p, x0, terms=terms, config=fine_cfg))
                   for m in meshes[1:]]
        spacings = [1e3 * h0 / 2 ** i for i in range(levels)]
        for seed in [int(s) for s in a.seeds.split(",")]:
            states, recs = [], []
            t0 = time.perf_counter()
            r = jax.block_until_ready(coarse(p, seed))
            if len(meshes) == 1 or a.polish_coarsest:  # its rest state solved with the terms as given
                q = jax.block_until_ready(polish(p, r.x))
                r = eqx.tree_at(lambda d: (d.newton_iters, d.status), q,
                                (r.newton_iters + q.newton_iters, polished_status(r.status, q.status)))
            recs.append((r, time.perf_counter() - t0))
            states.append(np.asarray(r.x))
            for lvl, (m, pr, solve) in enumerate(zip(meshes[1:], prolongs, statics), start=1):
                t0 = time.perf_counter()
                r = jax.block_until_ready(solve(p, pr(r.x, m)))
                recs.append((r, time.perf_counter() - t0))
                states.append(np.asarray(r.x))
            fine_faces = np.asarray(meshes[-1].faces)
            for lvl, ((r, sec), x, m) in enumerate(zip(recs, states, meshes)):
                dc, folds = dc_and_folds(x, m)
                scan = 0.0 if lvl == len(meshes) - 1 else scan_distance_mm(x, np.asarray(m.faces), states[-1],
                                                                            fine_faces, align_rotation=False)
                line = {"fabric": name, "row": row, "bending_length_mm": round(1e3 * length, 2),
                        "density_kg_m2": float(p.density), "seed": seed, "level": lvl,
                        "spacing_mm": spacings[lvl], "rim_mm": spacings[lvl] / rim_ratio, "verts": m.n_verts,
                        "status": STATUS_NAMES[int(r.status)], "newton_iters": int(r.newton_iters),
                        "seconds": round(sec, 2), "dc": dc, "folds": folds,
                        "scan_to_finest_mm": round(float(scan), 3), "force_tol": a.force_tol}
                rows.append(line)
                print(json.dumps(line), flush=True)
                if out:
                    out.write(json.dumps(line) + "\n")
                    out.flush()
    return rows


def _verts(h0: float, levels: int, rim_ratio: float) -> int:
    """Vertices of the finest level of a hierarchy from a coarsest spacing ``h0`` (an estimate:
    the coarsest mesh's count times 4 per level)."""
    from drapejax.mesh import cusick_mesh
    return cusick_mesh(h0, rim_spacing_m=h0 / rim_ratio).n_verts * 4 ** (levels - 1)


def summarize(rows: list[dict]) -> list[dict]:
    """Per fabric: seed-mean DC and fold-count median per level, and the Richardson limit."""
    out = []
    for name in dict.fromkeys(r["fabric"] for r in rows):
        fr = [r for r in rows if r["fabric"] == name]
        levels = sorted({r["level"] for r in fr})
        per = []
        for lvl in levels:
            lr = [r for r in fr if r["level"] == lvl]
            per.append({"spacing_mm": lr[0]["spacing_mm"], "rim_mm": lr[0]["rim_mm"], "verts": lr[0]["verts"],
                        "dc_mean": float(np.mean([r["dc"] for r in lr])),
                        "dc_std": float(np.std([r["dc"] for r in lr])),
                        "folds_median": float(np.median([r["folds"] for r in lr])),
                        "scan_to_finest_mm": float(np.mean([r["scan_to_finest_mm"] for r in lr])),
                        "seconds_median": float(np.median([r["seconds"] for r in lr])),
                        "newton_iters_median": float(np.median([r["newton_iters"] for r in lr])),
                        "at_rest": sum(r["status"] == "at_rest" for r in lr), "seeds": len(lr)})
        rich = richardson([p["dc_mean"] for p in per])
        s = {"summary": name, "bending_length_mm": fr[0]["bending_length_mm"], "density_kg_m2": fr[0]["density_kg_m2"],
             "levels": per, "richardson": rich,
             "finest_minus_limit": per[-1]["dc_mean"] - rich["limit"]}
        out.append(s)
    return out


def figure(summaries: list[dict], path: str) -> None:
    """Drape coefficient against spacing per fabric, with its Richardson limit dashed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=150)
    for s in summaries:
        h = [p["spacing_mm"] for p in s["levels"]]
        dc = [p["dc_mean"] for p in s["levels"]]
        err = [p["dc_std"] for p in s["levels"]]
        line = ax.errorbar(h, dc, yerr=err, marker="o", capsize=3,
                           label=f"{s['summary']} (c = {s['bending_length_mm']:.1f} mm)")
        ax.axhline(s["richardson"]["limit"], color=line[0].get_color(), ls="--", lw=0.8)
    ax.set_xscale("log", base=2)
    ticks = [3, 4, 6, 8, 12, 16, 20]
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.minorticks_off()
    ax.invert_xaxis()
    ax.set_xlabel("interior spacing of the level, mm (disc-edge spacing one fifth)")
    ax.set_ylabel("drape coefficient (seed mean ± std)")
    ax.set_title("Cusick drape on nested meshes\ndashed: Richardson limit (or the finest value)", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", default=str(TABLE), help="the 618-fabric CSV")
    ap.add_argument("--fabrics", default=",".join(PICKS), help="comma list of: softest, lightest, stiffest, "
                    "q10, q25, median, q75, q90 (table rows), light, mid, heavy (the embedded examples)")
    ap.add_argument("--prior-softest", type=int, default=0, metavar="N",
                    help="instead of --fabrics, the N softest of 200 draws of the inverse map's prior (seed 0)")
    ap.add_argument("--prior-skip", type=int, default=0, metavar="K", help="with --prior-softest: leave out the "
                    "softest K (to resume)")
    ap.add_argument("--spacing-mm", type=float, default=10.0, help="coarsest level's interior spacing")
    ap.add_argument("--rim-ratio", type=float, default=5.0, help="interior over disc-edge spacing on every level")
    ap.add_argument("--coarsest-over-length", type=float, default=None, help="coarsest spacing as this multiple "
                    "of each fabric's bending length (instead of --spacing-mm)")
    ap.add_argument("--max-verts", type=int, default=0, help="drop the finest levels of a fabric whose finest "
                    "mesh would have more vertices than this (0: no limit)")
    ap.add_argument("--levels", type=int, default=3, help="levels (each halves the spacing)")
    ap.add_argument("--default", default=None, metavar="MM",
                    help="instead of the levels above, drape on the hierarchy `drapejax simulate --spacing-mm MM` "
                         "uses (finest MM graded to MM/5 at the disc edge, coarsest as coarse as the fabric allows); "
                         "'auto': each fabric's default finest spacing (`drapejax simulate` without --spacing-mm, "
                         "solve.finest_spacing_m)")
    ap.add_argument("--polish-coarsest", action="store_true",
                    help="solve the coarsest level's rest state again with the terms as given, as `drapejax simulate` "
                         "does when that level is its finest: with --default MM/2, a fabric whose default is a single "
                         "level is carried one level finer from its default state")
    ap.add_argument("--seeds", default="0,1,2", help="comma list of drop seeds")
    ap.add_argument("--force-tol", type=float, default=1e-4, help="fine levels' SolverConfig.force_tol")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file as they come")
    ap.add_argument("--summarize", default=None, help="only summarise (and draw) an earlier --out file")
    ap.add_argument("--figure", default=None, help="write the convergence figure here (PNG)")
    a = ap.parse_args()
    if a.summarize:
        rows = [json.loads(line) for line in open(a.summarize) if line.strip()]
    else:
        rows = run(a)
    summaries = summarize(rows)
    for s in summaries:
        print(json.dumps(s), flush=True)
    if a.figure:
        figure(summaries, a.figure)


if __name__ == "__main__":
    main()
