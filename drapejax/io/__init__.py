"""Reader and writer of the drape measurement folder (spec/measurement-format.md).

A measurement folder holds ``measurement.json`` and the observation files it names
(silhouette PNG, height map NPY, photo PNG, scan PLY/OBJ), plus ``truth.json`` for
synthetic measurements. ``load_measurement`` validates everything and returns a fully
loaded, read-only ``Measurement`` or raises one ``MeasurementError`` that names the folder,
the file and the field; ``write_measurement`` validates its inputs the same way and writes
atomically (temporary sibling folder, then rename).

The package splits this by job: ``format`` (names and limits of the format), ``measurement``
(the ``Measurement`` record and ``MeasurementError``), ``bench`` (bench readings on strips of the
same fabric, optional), ``header`` (validation of
``measurement.json``), ``checks`` (validation of the observation arrays, shared by reader and
writer), ``reader`` (``load_measurement``, ``load_truth``), ``writer`` (``write_measurement``)
and ``build`` (``build_measurement``: a folder from a user's photo, scan, silhouette or height
map, behind ``drapejax measure``). Every public name is importable from ``drapejax.io`` itself.
"""

from __future__ import annotations

from .bench import BENCH_FIELDS, BENDING_TESTS, CUT_ANGLES_DEG, K1_OF_CUT, READING_STD, BenchRecord
from .build import build_measurement
from .format import (DEFAULT_FILES, FORMAT, MAX_AREAL_DENSITY_KG_M2, MAX_SPECIMEN_M, MEASUREMENT_FILE, OBSERVATIONS,
                     OUT_OF_REACH_FRACTION, REACH_FACTOR, RESERVED_KEYS, SKIRT_RISE_FRACTION, SPECIMEN_SHAPES,
                     TRUTH_FILE)
from .measurement import Measurement, MeasurementError
from .reader import load_measurement, load_truth
from .writer import write_measurement

__all__ = [
    "FORMAT", "MEASUREMENT_FILE", "TRUTH_FILE", "SPECIMEN_SHAPES", "OBSERVATIONS",
    "MeasurementError", "Measurement", "load_measurement", "load_truth", "write_measurement",
    "build_measurement", "DEFAULT_FILES", "MAX_AREAL_DENSITY_KG_M2", "MAX_SPECIMEN_M", "OUT_OF_REACH_FRACTION",
    "REACH_FACTOR", "RESERVED_KEYS", "SKIRT_RISE_FRACTION", "BenchRecord", "BENCH_FIELDS", "BENDING_TESTS",
    "CUT_ANGLES_DEG", "K1_OF_CUT", "READING_STD",
]
