"""Building a measurement folder from a user's own files: ``build_measurement``.

A drape tester's files come as they come: a photo of the drape with an ArUco marker, a scan
(triangle mesh or point cloud, .ply/.obj/.stl/.off/.xyz, perhaps in millimetres), a silhouette
image or a height map already on a grid, and the numbers written down beside the test (areal
density, warp angle). ``build_measurement`` turns them into one folder of the format
(docs/measurement-format.md) with the library's own pieces: the scan's top views are rendered
by ``drapejax.observe`` (``silhouette``/``height_map``, ``point_cloud_views`` for a cloud), the
folder is written by ``write_measurement``, read back by ``load_measurement`` and described by
``drapejax.observe.describe`` (which rectifies a photo with ``drapejax.photo``). So a folder it
returns loads, and one that would not is never left on disk.

It backs ``drapejax measure``: its keyword arguments are the command's options (``scan`` is
``--scan``), and every refusal is one ``MeasurementError`` line that names the option and the
user's file, followed by the format check's own words (the file and field of the folder, and the
slip it looks like: millimetres for metres, g/m² for kg/m²).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from pathlib import Path

import numpy as np

from .format import DEFAULT_FILES, MEASUREMENT_FILE, SPECIMEN_SHAPES
from .measurement import MeasurementError
from .reader import load_measurement
from .writer import _write_atomically, write_measurement

SCAN_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Length unit of a scan file -> metres per unit (the format is in metres)."""
SCAN_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".xyz")
"""Scan files trimesh reads as one mesh or point cloud (an .xyz file is a point cloud)."""
GRID_PX = 256
"""Side, pixels, of the silhouette and height map rendered from a scan (the format's default)."""
DEFAULT_MARKER = {"dictionary": "DICT_4X4_50", "id": 0, "center_m": (0.0, 0.0, 0.002)}
"""The photo's ArUco marker where not given: the format's example marker, centred on the clamp
2 mm above the disc top. Its side has no default: it sets the photo's scale."""

_FIELD_OPTIONS = (
    ("areal_density_kg_m2", "--density"), ("warp_angle_deg", "--warp-angle-deg"), ("test", "--test"),
    ("specimen.", "--specimen-radius-m"), ("support.", "--disk-radius-m"),
    ("photo.marker.side_m", "--marker-side-m"), ("photo.marker.center_m", "--marker-center-m"),
    ("photo.marker.id", "--marker-id"), ("photo.marker.dictionary", "--marker-dictionary"),
    ("photo.marker", "--marker-side-m/--marker-center-m"), ("silhouette.extent_m", "--extent-m"),
    ("height_map.extent_m", "--extent-m"), ("bench[", "--bench"),
)
"""measurement.json field (exact, or a prefix ending in '.' or '[') -> the option that sets it."""


def _fail(option: str, what, msg: str) -> MeasurementError:
    return MeasurementError(f"{option}{'' if what is None else f' {what}'}: {msg}")


def _input_file(path, option: str) -> Path:
    """The user's file ``path`` of ``option``, refused by name when missing or unreadable."""
    path = Path(path)
    if not path.exists():
        raise _fail(option, path, "file not found")
    if not path.is_file():
        raise _fail(option, path, "is not a file")
    if not os.access(path, os.R_OK):
        raise _fail(option, path, "cannot read the file (permission denied)")
    return path


def _read_scan(path: Path, unit: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertices (m) and faces (None for a point cloud) of a scan file. A mesh's coincident
    vertices are merged (an STL stores every triangle apart), so that its hem is its boundary."""
    import trimesh

    if path.suffix.lower() not in SCAN_SUFFIXES:
        raise _fail("--scan", path, f"unsupported scan file type {path.suffix or '(none)'!r}; expected one of "
                                    f"{', '.join(SCAN_SUFFIXES)}")
    try:
        geom = trimesh.load(str(path), file_type=path.suffix[1:].lower(), process=False)
        if isinstance(geom, trimesh.Scene) and geom.geometry:
            geom = geom.to_geometry()
    except Exception as e:
        raise _fail("--scan", path, f"trimesh cannot read it ({type(e).__name__}: {e})") from None
    if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
        geom.merge_vertices(merge_tex=True, merge_norm=True)
        faces = np.asarray(geom.faces)
    elif isinstance(geom, (trimesh.Trimesh, trimesh.PointCloud)):
        faces = None
    else:
        raise _fail("--scan", path, f"expected a triangle mesh or point cloud, got {type(geom).__name__}")
    vertices = np.asarray(geom.vertices, float) * SCAN_UNITS[unit]
    if len(vertices) == 0:
        raise _fail("--scan", path, "the file holds no points")
    return vertices, faces


def _scan_views(vertices: np.ndarray, faces: np.ndarray | None, extent_m: float):
    """Top-view silhouette and height map of the scan on the format's grid, rendered exactly as
    ``describe`` renders a scan (a cloud through its alpha-shape mesh)."""
    from ..observe import height_map, point_cloud_views, silhouette

    if faces is None:
        return point_cloud_views(vertices, n=GRID_PX, extent_m=extent_m)
    return (silhouette(vertices, faces, n=GRID_PX, extent_m=extent_m),
            height_map(vertices, faces, n=GRID_PX, extent_m=extent_m))


def _read_silhouette(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)  # a grey, RGB or 16-bit mask as 8-bit grey
    if img is None:
        raise _fail("--silhouette", path, "not a readable image")
    return img


def _read_height(path: Path) -> np.ndarray:
    try:
        h = np.load(path, allow_pickle=False)
    except Exception as e:
        raise _fail("--height", path, f"not a readable .npy array ({type(e).__name__}: {e})") from None
    if not isinstance(h, np.ndarray):
        raise _fail("--height", path, f"expected a single .npy array, got {type(h).__name__}")
    return h


def _reworded(e: Exception, staging: Path, out: Path, origins: dict, values: dict) -> MeasurementError:
    """``e`` (a refusal of the folder being staged, or of its photo) as one line that names the
    option and the user's file or value instead of the staging folder."""
    text = str(e)
    photo = f"{staging / DEFAULT_FILES['photo']}: "
    if text.startswith(photo):
        return _fail("--photo", origins[DEFAULT_FILES["photo"]][1], text[len(photo):])
    rest = text
    for folder in (staging, out):  # the writer names the staging folder, the final move ``out``
        rest = rest[len(f"{folder}: "):] if rest.startswith(f"{folder}: ") else rest
    field = re.match(r"[^:]*? field '([^']*)'", rest)
    field = field.group(1) if field else None
    for key, option in _FIELD_OPTIONS:
        if field is not None and (field == key or (key.endswith((".", "[")) and field.startswith(key))):
            value = values.get(option)
            return _fail(option, None if value is None else value, rest)
    name = rest.split(":", 1)[0].split(" field ", 1)[0]
    if name in origins:
        option, path = origins[name]
        unit_slip = option == "--scan" and re.search("millimetres|centimetres", rest)
        hint = " Pass --scan-unit mm or cm." if unit_slip else ""
        return _fail(option, path, rest + hint)
    return _fail("--out", out, rest)


def build_measurement(
    out: str | os.PathLike,
    *,
    areal_density_kg_m2: float | None,
    test: str = "cusick",
    photo: str | os.PathLike | None = None,
    marker_side_m: float | None = None,
    marker_id: int | None = None,
    marker_dictionary: str | None = None,
    marker_center_m: tuple[float, float, float] | None = None,
    scan: str | os.PathLike | None = None,
    scan_unit: str = "m",
    silhouette: str | os.PathLike | None = None,
    height: str | os.PathLike | None = None,
    extent_m: float | None = None,
    warp_angle_deg: float | None = None,
    specimen_radius_m: float | None = None,
    disk_radius_m: float | None = None,
    bench: str | os.PathLike | None = None,
    overwrite: bool = False,
) -> dict:
    """Write the measurement folder ``out`` from a user's files, read it back and describe it.

    The scan is stored as ``scan.ply`` (metres, coincident mesh vertices merged) and, unless a
    silhouette or height map is given, its top-view silhouette and height map are rendered onto
    the format's grid (``GRID_PX`` pixels over ``extent_m``, default ``observe.EXTENT_M``), as
    ``inspect`` would render the scan. A photo is stored with its marker and rectified to a
    silhouette by ``drapejax.photo.photo_silhouette`` once the folder is read back, so an
    undetected marker or a photo without its background fails here, not in a later estimate. The folder is staged beside
    ``out`` and moved into place only once it loads and describes; on any failure nothing is
    left (and an existing ``out`` is kept).

    Args:
        out: the folder to create.
        areal_density_kg_m2: kg/m²; None when the fabric was not weighed (estimates are then
            density-normalised, k/rho). No default: an unknown density must be said.
        test: "cusick" (circular specimen) or "square".
        photo: top-view photo file (any image OpenCV reads; stored as RGB PNG).
        marker_side_m: side of the marker's black square, m; required with ``photo``.
        marker_id, marker_dictionary, marker_center_m: the marker (``DEFAULT_MARKER`` where None).
        scan: scan file, a triangle mesh or point cloud (``SCAN_SUFFIXES``) in the world frame.
        scan_unit: "m", "cm" or "mm", the scan file's length unit.
        bench: a JSON file of bench readings on strips of the same fabric (a list of readings, or
            an object with that list under "bench"; docs/measurement-format.md), stored under
            "bench" in measurement.json.
        silhouette: silhouette image on the format's grid (fabric 255, else 0); needs ``extent_m``.
        height: float .npy height map, m, on the same grid (NaN off the fabric); needs ``extent_m``.
        extent_m: half width of the grid, m.
        warp_angle_deg: angle from +x to the warp, degrees; None = not recorded.
        specimen_radius_m, disk_radius_m: specimen radius (square: half side) and support-disc
            radius, m; None = the test's standard 0.15 and 0.09.
        overwrite: replace an existing ``out`` that is a measurement folder (holds
            ``measurement.json``); any other folder is refused, so a mistyped ``out`` loses no files.

    Returns:
        dict: "out", "test", "observations" (in the folder), "files" (name -> size in bytes), "sources"
        (observation -> where it came from), "areal_density_kg_m2", "warp_angle_deg",
        "specimen_radius_m", "disk_radius_m", "extent_m" (None without a grid), "scan" ({"points",
        "faces"} or None) and "descriptors" (``drapejax.observe.describe`` of the folder).

    Raises:
        MeasurementError: one line naming the option and file or value at fault; nothing written.
    """
    from ..mesh import CUSICK_RADIUS_M, DISK_RADIUS_M
    from ..observe import EXTENT_M, describe

    out = Path(out)
    if out.name in ("", ".", ".."):
        raise _fail("--out", out, "must name the folder to create")
    if out.exists() and not out.is_dir():
        raise _fail("--out", out, "exists and is not a folder")
    if out.exists() and not overwrite:
        raise _fail("--out", out, "already exists; pass --overwrite to replace it")
    if out.exists() and not (out / MEASUREMENT_FILE).is_file():  # never replace a folder of other files
        raise _fail("--out", out, f"exists and is not a measurement folder (no {MEASUREMENT_FILE}); "
                                  "--overwrite replaces only a measurement folder")
    if test not in SPECIMEN_SHAPES:
        raise _fail("--test", test, f"unknown test; expected one of {sorted(SPECIMEN_SHAPES)}")
    if all(x is None for x in (photo, scan, silhouette, height)):
        raise _fail("--photo/--scan/--silhouette/--height", None,
                    "at least one observation is required: a photo, a scan, a silhouette or a height map")
    if scan_unit not in SCAN_UNITS:
        raise _fail("--scan-unit", scan_unit, f"expected one of {sorted(SCAN_UNITS)}")
    if (silhouette is not None or height is not None) and extent_m is None:
        raise _fail("--extent-m", None, "required with --silhouette or --height: the half width of their grid, m")
    marker_given = [o for o, v in (("--marker-side-m", marker_side_m), ("--marker-id", marker_id),
                                   ("--marker-dictionary", marker_dictionary),
                                   ("--marker-center-m", marker_center_m)) if v is not None]
    if photo is None and marker_given:
        raise _fail(marker_given[0], None, "given without --photo")
    if photo is not None and marker_side_m is None:
        raise _fail("--marker-side-m", None, "required with --photo: the side of the ArUco marker's black "
                                             "square, m (it sets the photo's scale)")
    specimen_radius_m = CUSICK_RADIUS_M if specimen_radius_m is None else specimen_radius_m
    disk_radius_m = DISK_RADIUS_M if disk_radius_m is None else disk_radius_m
    grid_extent = EXTENT_M if extent_m is None else extent_m

    origins, sources, arrays, scan_info, marker = {}, {}, {}, None, None
    if photo is not None:
        from ..photo import PhotoError, read_photo

        photo = _input_file(photo, "--photo")
        try:
            arrays["photo"] = read_photo(photo)
        except PhotoError:
            raise _fail("--photo", photo, "not a readable image") from None
        marker = {"dictionary": marker_dictionary or DEFAULT_MARKER["dictionary"],
                  "id": DEFAULT_MARKER["id"] if marker_id is None else marker_id, "side_m": marker_side_m,
                  "center_m": list(DEFAULT_MARKER["center_m"] if marker_center_m is None else marker_center_m)}
        origins[DEFAULT_FILES["photo"]] = ("--photo", photo)
        sources["photo"] = photo.name
    if scan is not None:
        scan = _input_file(scan, "--scan")
        vertices, faces = _read_scan(scan, scan_unit)
        arrays["scan"] = (vertices, faces)
        scan_info = {"points": len(vertices), "faces": 0 if faces is None else len(faces)}
        origins[DEFAULT_FILES["scan"]] = ("--scan", scan)
        sources["scan"] = scan.name + ("" if scan_unit == "m" else f" (in {scan_unit})")
        if silhouette is None and height is None:
            try:
                arrays["silhouette"], arrays["height"] = _scan_views(vertices, faces, grid_extent)
            except ValueError as e:  # a cloud of fewer than 3 distinct points, say
                raise _fail("--scan", scan, f"cannot render its top view ({e})") from None
            for key in ("silhouette", "height_map"):
                origins[DEFAULT_FILES[key]] = ("--scan", scan)
                sources[key] = f"rendered from {scan.name}"
    if silhouette is not None:
        silhouette = _input_file(silhouette, "--silhouette")
        arrays["silhouette"] = _read_silhouette(silhouette)
        origins[DEFAULT_FILES["silhouette"]] = ("--silhouette", silhouette)
        sources["silhouette"] = silhouette.name
    if height is not None:
        height = _input_file(height, "--height")
        arrays["height"] = _read_height(height)
        origins[DEFAULT_FILES["height_map"]] = ("--height", height)
        sources["height_map"] = height.name

    readings = ()
    if bench is not None:
        bench = _input_file(bench, "--bench")
        try:
            readings = json.loads(bench.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise _fail("--bench", bench, f"not a JSON file ({e})") from None
        readings = readings.get("bench") if isinstance(readings, dict) else readings
        if not isinstance(readings, list) or not readings:
            raise _fail("--bench", bench, "must hold a list of bench readings (or an object with one under 'bench')")
        sources["bench"] = bench.name
    values = {"--bench": bench, "--density": areal_density_kg_m2, "--warp-angle-deg": warp_angle_deg, "--test": test,
              "--specimen-radius-m": specimen_radius_m, "--disk-radius-m": disk_radius_m,
              "--marker-side-m": marker_side_m, "--marker-id": None if marker is None else marker["id"],
              "--marker-dictionary": None if marker is None else marker["dictionary"],
              "--marker-center-m": None if marker is None else ",".join(f"{c:g}" for c in marker["center_m"]),
              "--extent-m": grid_extent}
    staging = out.parent / f".{out.name}.measure-{uuid.uuid4().hex[:12]}"
    try:
        write_measurement(staging, test=test, specimen_radius_m=specimen_radius_m, disk_radius_m=disk_radius_m,
                          areal_density_kg_m2=areal_density_kg_m2, warp_angle_deg=warp_angle_deg,
                          silhouette=arrays.get("silhouette"), height=arrays.get("height"), extent_m=grid_extent,
                          photo=arrays.get("photo"), photo_marker=marker, scan=arrays.get("scan"),
                          bench=readings, extra={"source": {"built_by": "drapejax measure", "from": sources}})
        m = load_measurement(staging)
        if m.has_photo:  # as an estimator reads it, also where a scan or silhouette makes describe skip it
            from ..photo import photo_silhouette

            photo_silhouette(m)
        descriptors = describe(m)
        files = {p.name: p.read_bytes() for p in sorted(staging.iterdir())}
        _write_atomically(out, files, overwrite)
    except (MeasurementError, ValueError) as e:  # PhotoError is a ValueError
        raise _reworded(e, staging, out, origins, values) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    observations = [k for k in ("silhouette", "height_map", "photo", "scan") if k in m.extra]
    return {
        "out": str(out), "test": test, "observations": observations,
        "files": {name: len(data) for name, data in files.items()}, "sources": sources,
        "areal_density_kg_m2": m.areal_density_kg_m2, "warp_angle_deg": m.warp_angle_deg,
        "specimen_radius_m": m.specimen_radius_m, "disk_radius_m": m.disk_radius_m,
        "extent_m": m.silhouette_extent_m or m.height_extent_m, "scan": scan_info, "descriptors": descriptors,
        "bench": [r.to_json() for r in m.bench],
    }


__all__ = ["SCAN_UNITS", "SCAN_SUFFIXES", "GRID_PX", "DEFAULT_MARKER", "build_measurement"]
