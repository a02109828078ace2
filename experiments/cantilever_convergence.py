"""Mesh convergence of the cantilever droop against the master curve, beyond the test grid.

The test (``tests/test_cantilever.py``) checks Γ = 0.1 and 100 at 5, 3.5 and 2.5 mm. This
study refines further and varies the strip width, to tell a discretisation error (shrinks
with the spacing) from a converged model error (does not), and an edge effect (scales with
1/width) from an interior one. One JSON line per case with the signed relative error
(H/W_sim − H/W_ref)/H/W_ref, then a summary line: the worst |error| per spacing and the signed
error at the finest spacing per width.

``--linear-beta B1,B2,...`` instead solves the small-deflection problem (Γ → 0, strip along the
warp) with the library's bending Hessian at the flat state as the stiffness, adding a
penalty β·D11·A_v·Σ_j (r_vj/ℓ_vj²)² on the part r_vj of each stencil's offsets that the
quadratic fit leaves unexplained (a 1-ring hourglass control; β = 0 is the bending energy
alone). It prints the tip-drop error against the beam, qL⁴/(8B), per width and spacing: a
diagnostic of the discretisation, not used by the library. ``--linear-cubic B1,...`` does the
same with the library's hourglass control at weight β (``energy.HourglassControl``, which
vanishes for cubic shapes; β = 0 is the bending alone, the library uses 3); with ``--angles``
the strips are cut at those angles to the warp.

    python -m experiments.cantilever_convergence
    python -m experiments.cantilever_convergence --spacings-mm 2.5,1.75 --gammas 0.1 --widths-mm 15
    python -m experiments.cantilever_convergence --linear-beta 0,0.3,1
    python -m experiments.cantilever_convergence --linear-cubic 0,3,10 --angles 0,90
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np


def linear_tip_error(width_m: float, spacing_m: float, beta: float = 0.0, length_m: float = 0.1, *,
                     cubic: float = 0.0, angle_deg: float = 0.0) -> float:
    """Small-deflection tip drop of a strip over the beam's qL⁴/(8B), minus 1 (see module docstring)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    from drapejax.energy import Bending, HourglassControl
    from drapejax.energy.bending import plate_terms
    from drapejax.material import strip_rigidity
    from drapejax.mesh import strip_mesh
    from drapejax.solve import term_hessian_coo
    from drapejax.validate import linear_params

    p = linear_params()
    m = strip_mesh(length_m, width_m, spacing_m, angle_deg=angle_deg)
    rest, cv, nb = np.asarray(m.rest), np.asarray(m.curv_verts), np.asarray(m.nbr)
    fit, area, n = np.asarray(m.fit), np.asarray(m.curv_area), rest.shape[0]

    def linear_stiffness(term):
        """z-z block of the term's Hessian at the flat rest state."""
        hr, hc, hv = (np.asarray(a) for a in term_hessian_coo(term, m.rest, m, p, project=False, exact=True))
        return sp.coo_matrix((hv, (hr, hc)), shape=(3 * n, 3 * n)).tocsr()[2::3][:, 2::3]

    stiff = linear_stiffness(Bending())
    if beta:
        d = rest[nb, :2] - rest[cv, None, :2]  # (c, k, 2)
        quad = np.stack([0.5 * d[..., 0] ** 2, d[..., 0] * d[..., 1], 0.5 * d[..., 1] ** 2], -1)
        design = np.concatenate([d, quad], -1)
        resid = np.eye(nb.shape[1])[None] - design @ fit  # (c, k, k): offsets → fit residual
        l2 = np.maximum(np.sum(d * d, -1), 1e-30)
        pad = nb == cv[:, None]  # padding slots repeat the centre: no residual
        w = np.where(pad, 0.0, area[:, None] / l2**2).ravel()
        # r_op: z → residuals Σ_k resid[c, j, k] (z_nbr_k − z_centre), one row per (vertex c, slot j)
        c, k = resid.shape[0], resid.shape[1]
        rr = np.broadcast_to(np.arange(c * k).reshape(c, k, 1), resid.shape)
        cc = np.broadcast_to(nb[:, None, :], resid.shape)
        r_op = (sp.coo_matrix((resid.ravel(), (rr.ravel(), cc.ravel())), shape=(c * k, n))
                - sp.coo_matrix((resid.sum(2).ravel(), (np.arange(c * k), np.repeat(cv, k))), shape=(c * k, n))).tocsr()
        d11 = float(plate_terms(p)[0])
        stiff = stiff + beta * d11 * r_op.T @ sp.diags(w) @ r_op
    if cubic:
        stiff = stiff + linear_stiffness(HourglassControl(beta=cubic))
    rigidity = float(strip_rigidity(p, angle_deg))
    q = 0.1 * rigidity / length_m**3  # ρg at Γ = 0.1, N/m²
    free = ~np.asarray(m.clamped)
    z = np.zeros(n)
    z[free] = spl.spsolve(stiff[free][:, free].tocsc(), -q * np.asarray(m.vertex_area)[free])
    tip = np.abs(rest[:, 0] - length_m) < 1e-9
    return float(-z[tip].mean() / (q * length_m**4 / (8 * rigidity)) - 1.0)


def _floats(s: str) -> list[float]:
    return [float(v) for v in s.split(",") if v]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacings-mm", type=_floats, default=_floats("5,3.5,2.5,1.75,1.25"))
    ap.add_argument("--gammas", type=_floats, default=_floats("0.1,1,10,100"))
    ap.add_argument("--widths-mm", type=_floats, default=_floats("7.5,15,30"))
    ap.add_argument("--angles", type=_floats, default=_floats("0,45"), help="strip angles to the warp, degrees")
    ap.add_argument("--linear-beta", type=_floats, default=None, help="small-deflection check with these penalties")
    ap.add_argument("--linear-cubic", type=_floats, default=None,
                    help="small-deflection check with these 2-ring cubic-residual penalties")
    a = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    if a.linear_beta is not None or a.linear_cubic is not None:
        kind, values = ("beta", a.linear_beta) if a.linear_beta is not None else ("cubic", a.linear_cubic)
        for ang in a.angles:
            for beta in values:
                for w in a.widths_mm:
                    for s in a.spacings_mm:
                        print(json.dumps({kind: beta, "angle_deg": ang, "width_mm": w, "spacing_mm": s,
                                          "tip_err": linear_tip_error(w / 1e3, s / 1e3, angle_deg=ang,
                                                                      **{kind: beta})}),
                              flush=True)
        return 0
    from drapejax.validate import cantilever_case

    rows = []
    for w in a.widths_mm:
        for s in a.spacings_mm:
            for g in a.gammas:
                for ang in a.angles:
                    t0 = time.perf_counter()
                    c = cantilever_case(g, ang, s / 1e3, width_m=w / 1e3)
                    row = {"width_mm": w, "spacing_mm": s, "gamma": g, "angle_deg": ang, "n_verts": c["n_verts"],
                           "hw_sim": c["hw_sim"], "hw_ref": c["hw_ref"],
                           "signed_err": (c["hw_sim"] - c["hw_ref"]) / c["hw_ref"],
                           "seconds": time.perf_counter() - t0}
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    finest = min(a.spacings_mm)
    summary = {
        "worst_abs_err_by_spacing_mm": {str(s): max(abs(r["signed_err"]) for r in rows if r["spacing_mm"] == s)
                                        for s in a.spacings_mm},
        "signed_err_at_finest_by_width_mm": {
            str(w): {f"gamma={g:g},angle={ang:g}": next(r["signed_err"] for r in rows if r["width_mm"] == w and
                                                        r["spacing_mm"] == finest and r["gamma"] == g and
                                                        r["angle_deg"] == ang)
                     for g in a.gammas for ang in a.angles}
            for w in a.widths_mm},
    }
    print(json.dumps({"summary": summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
