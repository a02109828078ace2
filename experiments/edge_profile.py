"""The skirt's height just past the disc edge: real scans against their baseline fits.

For each named fabric, the first capture is fitted as ``drapejax estimate`` fits it (network
estimate, then ``refine.fit`` on the default fit mesh), and the median height of the fitted rest
shape and of the scan is printed in rings of radius beyond the support disc (r = 90 mm). It
shows where the scans hang lower than the fits (the shared deficit of ``pooled_real.py``).
Usage: python experiments/edge_profile.py [f01 f14 ...] [--out edge.jsonl]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

from drapejax import refine
from drapejax.diagnose import initial_params
from drapejax.io import load_measurement
from drapejax.mesh import cusick_mesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_real import groups  # noqa: E402
from jsonl import emit  # noqa: E402

jax.config.update("jax_enable_x64", True)

EDGES_MM = (85.0, 87.5, 90.0, 92.5, 95.0, 100.0, 110.0, 120.0)
"""Ring boundaries (radius, mm); the support disc's edge is at 90 mm."""


def ring_heights_mm(verts: np.ndarray) -> list[float | None]:
    """Median z (mm) of the vertices in each ring of ``EDGES_MM`` (None where a ring is empty)."""
    r = 1e3 * np.hypot(verts[:, 0], verts[:, 1])
    out = []
    for a, b in zip(EDGES_MM[:-1], EDGES_MM[1:]):
        z = verts[(r >= a) & (r < b), 2]
        out.append(float(1e3 * np.median(z)) if z.size else None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fabrics", nargs="*", default=["f01", "f14"])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / "../shared/data/real_cusick")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    folders = groups(args.data.resolve())
    for fab in args.fabrics:
        m = load_measurement(folders[fab][0])
        mesh = cusick_mesh(refine.FIT_SPACING_M, warp_angle_deg=m.warp_angle_deg or 0.0,
                           rim_spacing_m=refine.FIT_RIM_SPACING_M)
        res = refine.fit(m, init=initial_params(m), spacing_m=refine.FIT_SPACING_M, mesh=mesh)
        emit({"fabric": fab, "capture": folders[fab][0].name, "rings_mm": list(zip(EDGES_MM[:-1], EDGES_MM[1:])),
              "scan_z_mm": ring_heights_mm(np.asarray(m.scan_vertices, float)),
              "fit_z_mm": ring_heights_mm(np.asarray(res.x)), "fit_status": res.status}, args.out)


if __name__ == "__main__":
    main()
