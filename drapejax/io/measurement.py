"""The loaded measurement (``Measurement``) and the error that names what breaks the format.

``MeasurementError`` messages name the folder, the file and the field; ``_Fail`` builds them
for one folder, so that the header checks, the observation checks, the reader and the writer
all word their refusals the same way.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from jaxtyping import Float, Float32, Int, UInt8

from .format import MEASUREMENT_FILE


class MeasurementError(ValueError):
    """A measurement folder (or writer input) that breaks the format; names folder, file, field."""


@dataclasses.dataclass(frozen=True, eq=False)
class Measurement:
    """One drape test as read from a measurement folder (SI units, arrays read-only).

    Attributes:
        path: the folder it was read from.
        test: "cusick" or "square".
        specimen_radius_m: circle radius or square half side, m.
        disk_radius_m: support disk radius, m.
        areal_density_kg_m2: areal density, kg/m²; None when the fabric was not weighed.
        warp_angle_deg: angle from +x to the warp, degrees; None when not recorded.
        tag: fabric description (category, composition, ...) or None.
        silhouette: (N, N) top view, 255 where fabric is seen, 0 elsewhere; row index grows
            with -y, column index with +x.
        silhouette_extent_m: the silhouette covers x, y in [-extent, extent], m.
        height: (N, N) height of the top fabric surface, m; NaN where no fabric.
        height_extent_m: as ``silhouette_extent_m`` for the height map, m.
        photo: (H, W, 3) RGB top photo.
        photo_marker: ArUco marker of the photo: ``dictionary`` (cv2.aruco name), ``id``,
            ``side_m`` and ``center_m`` (x, y, z in m).
        scan_vertices: (k, 3) scan points in the world frame, m.
        scan_faces: (j, 3) triangle vertex indices; None for a point cloud.
        extra: the raw ``measurement.json`` object (for extra keys such as "source").
        bench: bench readings on strips of the same fabric (``io.bench.BenchRecord``), () if none.
    """

    path: Path | None
    test: str
    specimen_radius_m: float
    disk_radius_m: float
    areal_density_kg_m2: float | None
    warp_angle_deg: float | None
    tag: dict | None
    silhouette: UInt8[np.ndarray, "n n"] | None
    silhouette_extent_m: float | None
    height: Float32[np.ndarray, "n n"] | None
    height_extent_m: float | None
    photo: UInt8[np.ndarray, "h w 3"] | None
    photo_marker: dict | None
    scan_vertices: Float[np.ndarray, "k 3"] | None
    scan_faces: Int[np.ndarray, "j 3"] | None
    extra: dict
    bench: tuple = ()

    @property
    def has_silhouette(self) -> bool:
        return self.silhouette is not None

    @property
    def has_height(self) -> bool:
        return self.height is not None

    @property
    def has_photo(self) -> bool:
        return self.photo is not None

    @property
    def has_scan(self) -> bool:
        return self.scan_vertices is not None

    @property
    def has_scan_mesh(self) -> bool:
        """The scan has faces, so it renders exactly; a bare point cloud goes through an alpha shape."""
        return self.scan_vertices is not None and self.scan_faces is not None and len(self.scan_faces) > 0


class _Fail:
    """Builds MeasurementErrors that name the folder and a file inside it."""

    def __init__(self, folder: Path):
        self.folder = folder

    def __call__(self, file: str, field: str | None, msg: str) -> MeasurementError:
        where = f"{file} field '{field}'" if field else file
        return MeasurementError(f"{self.folder}: {where}: {msg}")

    def json(self, field: str | None, msg: str) -> MeasurementError:
        return self(MEASUREMENT_FILE, field, msg)
