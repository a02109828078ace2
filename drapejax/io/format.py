"""The measurement format's names and limits (docs/measurement-format.md).

File and key names, the specimen shapes per test, and the bounds a header value or an
observation must respect: numbers beyond them are a unit slip (millimetres as metres, g/m² as
kg/m²) or a wrong frame, which reading and writing refuse alike.
"""

from __future__ import annotations

import math

FORMAT = "drapejax-measurement/1"
MEASUREMENT_FILE = "measurement.json"
TRUTH_FILE = "truth.json"
SPECIMEN_SHAPES = {"cusick": ("circle", "radius_m"), "square": ("square", "half_side_m")}
"""Test name -> (specimen shape, JSON key of its radius or half side)."""
OBSERVATIONS = ("silhouette", "height_map", "photo", "scan")
DEFAULT_FILES = {"silhouette": "silhouette.png", "height_map": "height.npy",
                 "photo": "photo.png", "scan": "scan.ply"}
RESERVED_KEYS = ("format", "test", "specimen", "support", "areal_density_kg_m2",
                 "warp_angle_deg", "tag", "bench") + OBSERVATIONS

MAX_SPECIMEN_M = 2.0
"""Largest specimen radius or half side accepted, m. Drape testers take 24-36 cm specimens; a
larger number is millimetres or centimetres written as metres, and would mesh a specimen of
that size."""
MAX_AREAL_DENSITY_KG_M2 = 10.0
"""Heaviest areal density accepted, kg/m² (the 618 measured fabrics span 0.015-0.87; a heavy
carpet is about 5): a larger number is g/m² written as kg/m²."""
REACH_FACTOR = 1.5
"""The specimen's material lies within its circumradius R of the disc centre and no higher above
the disc top than its overhang; observations may exceed that by this factor (stretch, scanner
noise, and a specimen laid off the centre: 1.5 R allows R/2, more than the overhang by which a
specimen can be off while it still covers the disc)."""
OUT_OF_REACH_FRACTION = 0.01
"""Fraction of scan points or fabric pixels allowed beyond that reach (stray points)."""
SKIRT_RISE_FRACTION = 0.01
"""The median height of the material beyond the disc edge may lie above the disc top by this
fraction of the overhang (scanner offset); gravity puts it below."""


def _circumradius(test: str, size_m: float) -> float:
    """Largest distance of the specimen's material from its centre, m (``size_m``: the circle's
    radius or the square's half side)."""
    return math.sqrt(2.0) * size_m if test == "square" else size_m
