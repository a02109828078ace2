"""Reader and writer of the drape measurement folder (spec/measurement-format.md).

A measurement folder holds ``measurement.json`` and the observation files it names
(silhouette PNG, height map NPY, photo PNG, scan PLY/OBJ), plus ``truth.json`` for
synthetic measurements. ``load_measurement`` validates everything and returns a fully
loaded, read-only ``Measurement`` or raises one ``MeasurementError`` that names the folder,
the file and the field; ``write_measurement`` validates its inputs the same way and writes
atomically (temporary sibling folder, then rename).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import shutil
import uuid
from pathlib import Path, PurePath

import cv2
import numpy as np
import trimesh
from jaxtyping import Float, Float32, Int, UInt8

from ..material import FabricParams, ParameterError

FORMAT = "drapejax-measurement/1"
MEASUREMENT_FILE = "measurement.json"
TRUTH_FILE = "truth.json"
SPECIMEN_SHAPES = {"cusick": ("circle", "radius_m"), "square": ("square", "half_side_m")}
"""Test name -> (specimen shape, JSON key of its radius or half side)."""
OBSERVATIONS = ("silhouette", "height_map", "photo", "scan")
DEFAULT_FILES = {"silhouette": "silhouette.png", "height_map": "height.npy",
                 "photo": "photo.png", "scan": "scan.ply"}
RESERVED_KEYS = ("format", "test", "specimen", "support", "areal_density_kg_m2",
                 "warp_angle_deg", "tag") + OBSERVATIONS

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_SCAN_SUFFIXES = (".ply", ".obj")
_MAX_MIDTONE_FRACTION = 0.1
"""A silhouette may have anti-aliased edges, but more than this fraction of pixels in
32..223 means the image is not a fabric mask."""
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


# ---------------------------------------------------------------------------------------
# measurement.json


def _number(value, fail: _Fail, field: str, *, positive: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise fail.json(field, f"must be a number, got {value!r}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x) or (positive and x <= 0):
        kind = "a positive finite number" if positive else "a finite number"
        raise fail.json(field, f"must be {kind}, got {value!r}")
    return x


def _object(raw: dict, key: str, fail: _Fail, prefix: str = "") -> dict:
    if key not in raw:
        raise fail.json(prefix + key, "missing required key")
    if not isinstance(raw[key], dict):
        raise fail.json(prefix + key, f"must be a JSON object, got {raw[key]!r}")
    return raw[key]


def _file_name(entry: dict, fail: _Fail, field: str) -> str:
    name = entry.get("file")
    if not isinstance(name, str) or not name.strip():
        raise fail.json(f"{field}.file", f"must be a file name, got {name!r}")
    rel = PurePath(name)
    if rel.is_absolute() or ".." in rel.parts:
        raise fail.json(f"{field}.file", f"must name a file inside the folder, got {name!r}")
    return name


def _marker(entry: dict, fail: _Fail) -> dict:
    marker = _object(entry, "marker", fail, "photo.")
    name = marker.get("dictionary")
    if not isinstance(name, str) or not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise fail.json("photo.marker.dictionary",
                        f"must name a cv2.aruco dictionary such as 'DICT_4X4_50', got {name!r}")
    size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0]
    marker_id = marker.get("id")
    if isinstance(marker_id, bool) or not isinstance(marker_id, int) or not 0 <= marker_id < size:
        raise fail.json("photo.marker.id", f"must be an integer id in [0, {size}) of {name}, "
                                           f"got {marker_id!r}")
    side = _number(marker.get("side_m"), fail, "photo.marker.side_m", positive=True)
    center = marker.get("center_m")
    if not isinstance(center, list) or len(center) != 3:
        raise fail.json("photo.marker.center_m", f"must be [x, y, z] in m, got {center!r}")
    center = tuple(_number(c, fail, "photo.marker.center_m", positive=False) for c in center)
    return {"dictionary": name, "id": marker_id, "side_m": side, "center_m": center}


def _circumradius(test: str, size_m: float) -> float:
    """Largest distance of the specimen's material from its centre, m (``size_m``: the circle's
    radius or the square's half side)."""
    return math.sqrt(2.0) * size_m if test == "square" else size_m


def _marker_on_the_clamp(marker: dict, circumradius: float, disk: float, fail: _Fail) -> None:
    """The marker lies flat on the top clamp: refuse one that could not (a side or centre in
    millimetres, say), with ``REACH_FACTOR``'s margin on the disc and on the overhang."""
    x, y, z = marker["center_m"]
    corner = math.hypot(x, y) + marker["side_m"] / math.sqrt(2.0)
    if corner > REACH_FACTOR * disk:
        raise fail.json("photo.marker", f"a {marker['side_m']:g} m marker centred {math.hypot(x, y):g} m from the "
                                        f"disc centre reaches {corner:.3g} m out; it lies on the top clamp, over the "
                                        f"{disk:g} m disc (side_m and center_m are in metres)")
    if abs(z) > REACH_FACTOR * (circumradius - disk):
        raise fail.json("photo.marker.center_m", f"z = {z:g} m is not on the top clamp, just above the disc top "
                                                 f"(z = 0; metres)")


def _parse_header(raw, fail: _Fail) -> dict:
    """Validate the measurement.json object; return its normalised fields."""
    if not isinstance(raw, dict):
        raise fail.json(None, f"must hold a JSON object, got {type(raw).__name__}")
    if "format" not in raw:
        raise fail.json("format", f"missing required key (expected {FORMAT!r})")
    if raw["format"] != FORMAT:
        raise fail.json("format", f"expected {FORMAT!r}, got {raw['format']!r}")
    if "test" not in raw:
        raise fail.json("test", "missing required key")
    test = raw["test"]
    if not isinstance(test, str) or test not in SPECIMEN_SHAPES:
        raise fail.json("test", f"unknown test {test!r}; expected one of {sorted(SPECIMEN_SHAPES)}")
    shape, size_key = SPECIMEN_SHAPES[test]
    specimen = _object(raw, "specimen", fail)
    if specimen.get("shape") != shape:
        raise fail.json("specimen.shape", f"a {test!r} test needs a {shape!r} specimen, "
                                          f"got {specimen.get('shape')!r}")
    if size_key not in specimen:
        raise fail.json(f"specimen.{size_key}", "missing required key")
    radius = _number(specimen[size_key], fail, f"specimen.{size_key}", positive=True)
    if radius > MAX_SPECIMEN_M:
        raise fail.json(f"specimen.{size_key}", f"{radius:g} m is larger than any drape test's specimen "
                                                f"(at most {MAX_SPECIMEN_M:g} m accepted); the format is in "
                                                f"metres: 150 mm is 0.15")
    support = _object(raw, "support", fail)
    if "disk_radius_m" not in support:
        raise fail.json("support.disk_radius_m", "missing required key")
    disk = _number(support["disk_radius_m"], fail, "support.disk_radius_m", positive=True)
    if disk >= radius:
        raise fail.json("support.disk_radius_m", f"the disk ({disk} m) must be smaller than the "
                                                 f"specimen ({size_key} = {radius} m)")
    if "areal_density_kg_m2" not in raw:
        raise fail.json("areal_density_kg_m2", "missing required key (use null if not weighed)")
    density = raw["areal_density_kg_m2"]
    if density is not None:
        density = _number(density, fail, "areal_density_kg_m2", positive=True)
        if density > MAX_AREAL_DENSITY_KG_M2:
            raise fail.json("areal_density_kg_m2", f"{density:g} kg/m² is heavier than any fabric (at most "
                                                   f"{MAX_AREAL_DENSITY_KG_M2:g} accepted); 200 g/m² is 0.2 kg/m²")
    warp = raw.get("warp_angle_deg", 0.0)
    if warp is not None:
        warp = _number(warp, fail, "warp_angle_deg", positive=False)
    tag = raw.get("tag")
    if tag is not None and not isinstance(tag, dict):
        raise fail.json("tag", f"must be a JSON object or null, got {tag!r}")
    entries = {}
    for key in OBSERVATIONS:
        if raw.get(key) is None:
            continue
        entry = _object(raw, key, fail)
        parsed = {"file": _file_name(entry, fail, key)}
        if key in ("silhouette", "height_map"):
            if "extent_m" not in entry:
                raise fail.json(f"{key}.extent_m", "missing required key")
            parsed["extent_m"] = _number(entry["extent_m"], fail, f"{key}.extent_m", positive=True)
        if key == "photo":
            parsed["marker"] = _marker(entry, fail)
            _marker_on_the_clamp(parsed["marker"], _circumradius(test, radius), disk, fail)
        if key == "scan" and PurePath(parsed["file"]).suffix.lower() not in _SCAN_SUFFIXES:
            raise fail.json("scan.file", f"must be a .ply or .obj file, got {parsed['file']!r}")
        entries[key] = parsed
    if not entries:
        raise fail.json("silhouette/height_map/photo/scan",
                        f"at least one observation is required, found none of {list(OBSERVATIONS)}")
    if "silhouette" in entries and "height_map" in entries:
        if entries["silhouette"]["extent_m"] != entries["height_map"]["extent_m"]:
            raise fail.json("height_map.extent_m",
                            f"the height map must share the silhouette grid: extent_m "
                            f"{entries['height_map']['extent_m']} != silhouette.extent_m "
                            f"{entries['silhouette']['extent_m']}")
    return dict(test=test, specimen_radius_m=radius, disk_radius_m=disk,
                areal_density_kg_m2=density, warp_angle_deg=warp, tag=tag, entries=entries)


def _reject_constant(name: str):
    raise ValueError(f"non-standard JSON constant {name}")


def _read_json(folder: Path, name: str, fail: _Fail):
    path = folder / name
    try:
        text = path.read_bytes().decode("utf-8")
        return json.loads(text, parse_constant=_reject_constant)
    except FileNotFoundError:
        raise fail(name, None, "file not found") from None
    except OSError as e:
        raise fail(name, None, f"cannot read the file ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise fail(name, None, "invalid JSON: not UTF-8 text") from None
    except json.JSONDecodeError as e:
        raise fail(name, None, f"invalid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except (ValueError, RecursionError) as e:
        raise fail(name, None, f"invalid JSON: {e}") from None


# ---------------------------------------------------------------------------------------
# arrays (shared by reader and writer)


def _silhouette_mask(img: np.ndarray, fail: _Fail, file: str) -> np.ndarray:
    if img.ndim != 2:
        raise fail(file, "silhouette", f"expected an 8-bit grey image, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise fail(file, "silhouette", f"expected 8-bit grey pixels, got {img.dtype}")
    if img.shape[0] != img.shape[1] or img.size == 0:
        raise fail(file, "silhouette", f"expected a square N x N image, got {img.shape}")
    midtone = np.mean((img >= 32) & (img <= 223))
    if midtone > _MAX_MIDTONE_FRACTION:
        raise fail(file, "silhouette", f"not a fabric mask: {midtone:.0%} of pixels are neither "
                                       f"near 0 nor near 255")
    if not np.any(img > 127):
        raise fail(file, "silhouette", f"shows no fabric (no pixel > 127, max {img.max()}); "
                                       "fabric pixels must be 255")
    return np.where(img > 127, np.uint8(255), np.uint8(0))


def _height_map(h: np.ndarray, fail: _Fail, file: str, silhouette: np.ndarray | None) -> np.ndarray:
    if h.ndim != 2 or h.shape[0] != h.shape[1] or h.size == 0:
        raise fail(file, "height_map", f"expected a square N x N array, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.floating):
        raise fail(file, "height_map", f"expected float32 heights in m, got {h.dtype}")
    h = h.astype(np.float32)
    if np.any(np.isinf(h)):
        raise fail(file, "height_map", f"{int(np.sum(np.isinf(h)))} infinite values "
                                       "(only NaN is allowed, where there is no fabric)")
    if np.all(np.isnan(h)):
        raise fail(file, "height_map", "all NaN: the height map shows no fabric")
    if silhouette is not None:
        if silhouette.shape != h.shape:
            raise fail(file, "height_map", f"grid {h.shape} differs from the silhouette grid "
                                           f"{silhouette.shape}")
        fabric = silhouette == 255
        holes = int(np.sum(fabric & np.isnan(h)))
        if holes:
            raise fail(file, "height_map", f"NaN at {holes} pixels where the silhouette shows fabric")
        stray = int(np.sum(~fabric & ~np.isnan(h)))
        if stray:
            raise fail(file, "height_map", f"finite heights at {stray} pixels where the silhouette "
                                           "shows no fabric (must be NaN)")
    return h


def _photo(img: np.ndarray, fail: _Fail, file: str) -> np.ndarray:
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise fail(file, "photo", f"expected an RGB image (H x W x 3), got shape {img.shape}")
    if img.dtype != np.uint8:
        raise fail(file, "photo", f"expected 8-bit RGB pixels, got {img.dtype}")
    return img


def _within_reach(points: np.ndarray, head: dict, fail: _Fail, file: str, field: str, what: str) -> None:
    """Raise if more than ``OUT_OF_REACH_FRACTION`` of ``points`` (k, 3) in m (z NaN: not
    checked) lie where the header's specimen cannot reach (see ``REACH_FACTOR``), or the
    material beyond the disc edge stands above the disc top, naming the likely slip:
    millimetres or centimetres, a y-up or z-down export, an origin off the disc centre."""
    rc = _circumradius(head["test"], head["specimen_radius_m"])
    overhang = rc - head["disk_radius_m"]
    far, low, high = REACH_FACTOR * rc, -REACH_FACTOR * rc, REACH_FACTOR * overhang
    r, z = np.hypot(points[:, 0], points[:, 1]), points[:, 2]
    frame = "The format is in metres, z up, origin at the centre of the disc top."
    with np.errstate(invalid="ignore"):
        out = (r > far) | (z < low) | (z > high)
    if np.mean(out) > OUT_OF_REACH_FRACTION:
        scale = max(float(np.max(r)), float(np.nanmax(np.abs(z), initial=0.0))) / rc
        hint = (" Is it in millimetres (divide by 1000)?" if scale > 300 else
                " Is it in centimetres (divide by 100)?" if scale > 30 else
                " Is its vertical axis y (a y-up export)?" if np.nanmax(z, initial=-np.inf) > high else "")
        zs = "" if np.all(np.isnan(z)) else f", z from {np.nanmin(z):.3g} to {np.nanmax(z):.3g} m"
        raise fail(file, field, f"{int(np.sum(out))} of {len(out)} {what} lie where a specimen of "
                                f"{head['specimen_radius_m']:g} m on a {head['disk_radius_m']:g} m disc cannot reach "
                                f"(beyond {far:.3g} m from the disc centre, or z outside [{low:.3g}, {high:.3g}] "
                                f"m); they reach {np.max(r):.3g} m from the origin{zs}. {frame}{hint}")
    skirt = z[(r > head["disk_radius_m"]) & np.isfinite(z)]
    if len(skirt) and np.median(skirt) > SKIRT_RISE_FRACTION * overhang:
        raise fail(file, field, f"the {what} beyond the disc edge stand above the disc top (median z "
                                f"{np.median(skirt):.3g} m), where gravity hangs them below it. {frame} "
                                f"Is z pointing down, or the origin below the disc top?")


def _grid_points(image: np.ndarray, extent_m: float, values: np.ndarray | None) -> np.ndarray:
    """(k, 3) world x, y of the fabric pixels of an N x N grid (``image`` 255 or finite
    ``values``), z from ``values`` (NaN without)."""
    from ..observe.render import pixel_centres  # lazy: importing observe would slow every import of io by 0.7 s

    c = pixel_centres(image.shape[0], extent_m)
    rows, cols = np.nonzero(image)
    z = np.full(len(rows), np.nan) if values is None else values[rows, cols].astype(np.float64)
    return np.stack([c[cols], -c[rows], z], 1)


def _observations_within_reach(head: dict, fail: _Fail, files: dict, extents: dict, silhouette, height,
                               scan) -> None:
    """Check the silhouette's and height map's fabric pixels and the scan points (any may be
    None) against the specimen's reach (``_within_reach``); ``files`` and ``extents`` by
    observation name."""
    if silhouette is not None:
        _within_reach(_grid_points(silhouette == 255, extents["silhouette"], None), head, fail, files["silhouette"],
                      "silhouette", f"fabric pixels (on a grid of extent_m {extents['silhouette']:g})")
    if height is not None:
        _within_reach(_grid_points(np.isfinite(height), extents["height_map"], height), head, fail,
                      files["height_map"], "height_map",
                      f"fabric pixels (on a grid of extent_m {extents['height_map']:g})")
    if scan is not None:
        _within_reach(scan, head, fail, files["scan"], "scan", "points")


def _scan(vertices: np.ndarray, faces: np.ndarray | None, fail: _Fail, file: str):
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise fail(file, "scan", f"expected k x 3 vertices with k > 0, got shape {vertices.shape}")
    if not np.issubdtype(vertices.dtype, np.number) or np.issubdtype(vertices.dtype, np.complexfloating):
        raise fail(file, "scan", f"vertices must be real numbers, got {vertices.dtype}")
    vertices = vertices.astype(np.float64)
    if not np.all(np.isfinite(vertices)):
        raise fail(file, "scan", f"{int(np.sum(~np.isfinite(vertices).all(1)))} vertices are not finite")
    if faces is None or len(faces) == 0:
        return vertices, None
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise fail(file, "scan", f"faces must be a j x 3 integer array, got {faces.dtype} "
                                 f"{faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise fail(file, "scan", f"face indices must lie in [0, {len(vertices)}), got "
                                 f"[{faces.min()}, {faces.max()}]")
    return vertices, faces.astype(np.int64)


def _read_only(a: np.ndarray | None) -> np.ndarray | None:
    if a is not None:
        a.setflags(write=False)
    return a


# ---------------------------------------------------------------------------------------
# reading


def _read_bytes(path: Path, fail: _Fail, file: str, field: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise fail(file, None, f"file not found (named by {MEASUREMENT_FILE} field "
                               f"'{field}.file')") from None
    except OSError as e:
        raise fail(file, None, f"cannot read the file ({e.strerror or e})") from None


def _read_png(folder: Path, file: str, fail: _Fail, field: str) -> np.ndarray:
    data = _read_bytes(folder / file, fail, file, field)
    if not data.startswith(_PNG_SIGNATURE):
        raise fail(file, field, "not a PNG file")
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as e:
        raise fail(file, field, f"cannot decode the PNG ({e.err})") from None
    if img is None:
        raise fail(file, field, "cannot decode the PNG (corrupt or truncated)")
    return img


def _read_npy(folder: Path, file: str, fail: _Fail) -> np.ndarray:
    data = _read_bytes(folder / file, fail, file, "height_map")
    try:
        arr = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as e:
        raise fail(file, "height_map", f"not a readable .npy array ({type(e).__name__}: {e})") from None
    if not isinstance(arr, np.ndarray):
        raise fail(file, "height_map", f"expected a single .npy array, got {type(arr).__name__}")
    return arr


def _read_scan(folder: Path, file: str, fail: _Fail):
    data = _read_bytes(folder / file, fail, file, "scan")
    try:
        geom = trimesh.load(io.BytesIO(data), file_type=PurePath(file).suffix[1:].lower(),
                            process=False)
        if isinstance(geom, trimesh.Scene) and geom.geometry:
            geom = geom.to_geometry()
    except Exception as e:
        raise fail(file, "scan", f"trimesh cannot read it ({type(e).__name__}: {e})") from None
    if isinstance(geom, trimesh.Scene):
        raise fail(file, "scan", "the file holds no mesh or points")
    if not isinstance(geom, (trimesh.Trimesh, trimesh.PointCloud)):
        raise fail(file, "scan", f"expected a triangle mesh or point cloud, got {type(geom).__name__}")
    faces = np.asarray(geom.faces) if isinstance(geom, trimesh.Trimesh) else None
    return _scan(np.asarray(geom.vertices), faces, fail, file)


def load_measurement(folder: str | os.PathLike) -> Measurement:
    """Read and validate a measurement folder.

    Raises:
        MeasurementError: the first problem found, naming the folder, file and field.
    """
    folder = Path(folder)
    fail = _Fail(folder)
    if not folder.is_dir():
        raise MeasurementError(f"{folder}: measurement folder not found"
                               if not folder.exists() else f"{folder}: is not a folder")
    raw = _read_json(folder, MEASUREMENT_FILE, fail)
    head = _parse_header(raw, fail)
    entries = head.pop("entries")
    silhouette = height = photo = vertices = faces = None
    if "silhouette" in entries:
        file = entries["silhouette"]["file"]
        silhouette = _silhouette_mask(_read_png(folder, file, fail, "silhouette"), fail, file)
    if "height_map" in entries:
        file = entries["height_map"]["file"]
        height = _height_map(_read_npy(folder, file, fail), fail, file, silhouette)
    if "photo" in entries:
        file = entries["photo"]["file"]
        bgr = _photo(_read_png(folder, file, fail, "photo"), fail, file)
        photo = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    if "scan" in entries:
        vertices, faces = _read_scan(folder, entries["scan"]["file"], fail)
    _observations_within_reach(head, fail, {k: e["file"] for k, e in entries.items()},
                               {k: e.get("extent_m") for k, e in entries.items()}, silhouette, height, vertices)
    return Measurement(
        path=folder, **head,
        silhouette=_read_only(silhouette),
        silhouette_extent_m=entries.get("silhouette", {}).get("extent_m"),
        height=_read_only(height),
        height_extent_m=entries.get("height_map", {}).get("extent_m"),
        photo=_read_only(photo),
        photo_marker=entries.get("photo", {}).get("marker"),
        scan_vertices=_read_only(vertices),
        scan_faces=_read_only(faces),
        extra=raw,
    )


def load_truth(folder: str | os.PathLike) -> dict | None:
    """Ground truth of a synthetic measurement (``truth.json``), or None if absent.

    For evaluation code only: estimators must never read it.
    """
    folder = Path(folder)
    fail = _Fail(folder)
    if not folder.is_dir():
        raise MeasurementError(f"{folder}: measurement folder not found")
    if not (folder / TRUTH_FILE).exists():
        return None
    truth = _read_json(folder, TRUTH_FILE, fail)
    if not isinstance(truth, dict):
        raise fail(TRUTH_FILE, None, f"must hold a JSON object, got {type(truth).__name__}")
    for key in ("params", "effects", "mesh"):
        if key in truth and not isinstance(truth[key], dict):
            raise fail(TRUTH_FILE, key, f"must be a JSON object, got {truth[key]!r}")
    return truth


# ---------------------------------------------------------------------------------------
# writing


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "__array__"):
        return np.asarray(obj).tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _jsonable(value, fail: _Fail, file: str, field: str):
    """Plain-JSON copy of ``value`` (NaN kept, for the field checks to name it)."""
    try:
        return json.loads(json.dumps(value, default=_json_default))
    except (TypeError, ValueError, RecursionError) as e:
        raise fail(file, field, f"cannot be written as JSON ({e})") from None


def _dump_json(obj: dict, fail: _Fail, file: str) -> bytes:
    for key, value in obj.items():
        try:
            json.dumps(value, allow_nan=False)
        except ValueError:
            raise fail(file, key, "contains NaN or infinity, which JSON cannot hold") from None
    return (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode("utf-8")


def _png_bytes(img: np.ndarray, fail: _Fail, file: str, field: str) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise fail(file, field, "OpenCV could not encode the image as PNG")
    return buf.tobytes()


def _ply_bytes(vertices: np.ndarray, faces: np.ndarray | None) -> bytes:
    """Binary little-endian PLY with float64 vertices (trimesh's exporter rounds to float32)."""
    header = ["ply", "format binary_little_endian 1.0", "comment drapejax scan",
              f"element vertex {len(vertices)}",
              "property double x", "property double y", "property double z"]
    body = [np.ascontiguousarray(vertices, "<f8").tobytes()]
    if faces is not None:
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        packed = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
        packed["n"] = 3
        packed["idx"] = faces
        body.append(packed.tobytes())
    return ("\n".join(header + ["end_header"]) + "\n").encode("ascii") + b"".join(body)


def _as_array(value, fail: _Fail, file: str, field: str) -> np.ndarray:
    try:
        return np.asarray(value)
    except Exception as e:
        raise fail(file, field, f"cannot be converted to an array ({e})") from None


def write_measurement(
    folder: str | os.PathLike,
    *,
    test: str,
    specimen_radius_m: float,
    disk_radius_m: float,
    areal_density_kg_m2: float | None,
    warp_angle_deg: float | None = 0.0,
    tag: dict | None = None,
    silhouette: np.ndarray | None = None,
    extent_m: float = 0.16,
    height: np.ndarray | None = None,
    photo: np.ndarray | None = None,
    photo_marker: dict | None = None,
    scan: tuple[np.ndarray, np.ndarray | None] | None = None,
    truth: dict | None = None,
    extra: dict | None = None,
    overwrite: bool = False,
) -> Path:
    """Write one measurement folder exactly per the spec, atomically.

    Args:
        folder: the folder to create (its parent is created if needed).
        test: "cusick" or "square".
        specimen_radius_m: circle radius or square half side, m.
        disk_radius_m: support disk radius, m.
        areal_density_kg_m2: kg/m², or None when not weighed.
        warp_angle_deg: angle from +x to the warp, degrees; None = not recorded.
        tag: optional fabric description.
        silhouette: (N, N) bool, or uint8 0/255, top view (row index grows with -y).
        extent_m: half width of the silhouette / height-map grid, m.
        height: (N, N) float heights in m, NaN where no fabric; stored as float32.
        photo: (H, W, 3) uint8 RGB photo; needs ``photo_marker``.
        photo_marker: {"dictionary", "id", "side_m", "center_m"} of the ArUco marker.
        scan: (vertices (k, 3) m, faces (j, 3) or None for a point cloud).
        truth: {"params": flat SI parameter dict or FabricParams, "effects": ..., "mesh": ...}
            written to truth.json.
        extra: additional top-level keys for measurement.json (e.g. "source").
        overwrite: replace an existing folder.

    Returns:
        The folder path.

    Raises:
        MeasurementError: invalid input (nothing is written) or an unwritable target.
    """
    folder = Path(folder)
    fail = _Fail(folder)
    if folder.exists() and not folder.is_dir():
        raise MeasurementError(f"{folder}: exists and is not a folder")
    if folder.exists() and not overwrite:
        raise MeasurementError(f"{folder}: already exists; pass overwrite=True to replace it")
    if not isinstance(test, str) or test not in SPECIMEN_SHAPES:
        raise fail.json("test", f"unknown test {test!r}; expected one of {sorted(SPECIMEN_SHAPES)}")
    shape, size_key = SPECIMEN_SHAPES[test]
    raw = {
        "format": FORMAT,
        "test": test,
        "specimen": {"shape": shape, size_key: specimen_radius_m},
        "support": {"disk_radius_m": disk_radius_m},
        "areal_density_kg_m2": areal_density_kg_m2,
        "warp_angle_deg": warp_angle_deg,
    }
    if tag is not None:
        raw["tag"] = tag
    if silhouette is not None:
        raw["silhouette"] = {"file": DEFAULT_FILES["silhouette"], "extent_m": extent_m}
    if height is not None:
        raw["height_map"] = {"file": DEFAULT_FILES["height_map"], "extent_m": extent_m}
    if photo is not None:
        raw["photo"] = {"file": DEFAULT_FILES["photo"], "marker": photo_marker}
    if scan is not None:
        raw["scan"] = {"file": DEFAULT_FILES["scan"]}
    if extra is not None:
        if not isinstance(extra, dict):
            raise fail.json(None, f"extra keys must be given as a dict, got {type(extra).__name__}")
        clash = sorted(set(extra) & set(RESERVED_KEYS))
        if clash:
            raise fail.json(clash[0], "is a format key and cannot be passed in 'extra'")
        raw.update(extra)
    raw = {key: _jsonable(value, fail, MEASUREMENT_FILE, key) for key, value in raw.items()}
    if photo is None and photo_marker is not None:
        raise fail.json("photo.marker", "given without a photo")
    if photo is not None and photo_marker is None:
        raise fail.json("photo.marker", "missing: a photo needs its ArUco marker description")
    head = _parse_header(raw, fail)

    files = {MEASUREMENT_FILE: _dump_json(raw, fail, MEASUREMENT_FILE)}
    mask = None
    if silhouette is not None:
        file = DEFAULT_FILES["silhouette"]
        sil = _as_array(silhouette, fail, file, "silhouette")
        if sil.dtype == bool:
            sil = sil.astype(np.uint8) * np.uint8(255)
        mask = _silhouette_mask(sil, fail, file)
        files[file] = _png_bytes(mask, fail, file, "silhouette")
    if height is not None:
        file = DEFAULT_FILES["height_map"]
        h = _height_map(_as_array(height, fail, file, "height_map"), fail, file, mask)
        buf = io.BytesIO()
        np.save(buf, h, allow_pickle=False)
        files[file] = buf.getvalue()
    if photo is not None:
        file = DEFAULT_FILES["photo"]
        rgb = _photo(_as_array(photo, fail, file, "photo"), fail, file)
        files[file] = _png_bytes(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), fail, file, "photo")
    if scan is not None:
        file = DEFAULT_FILES["scan"]
        if not isinstance(scan, (tuple, list)) or len(scan) != 2:
            raise fail(file, "scan", "must be a (vertices, faces) tuple, faces None for points")
        v = _as_array(scan[0], fail, file, "scan")
        f = None if scan[1] is None else _as_array(scan[1], fail, file, "scan")
        vertices, faces = _scan(v, f, fail, file)
        files[file] = _ply_bytes(vertices, faces)
    _observations_within_reach(head, fail, DEFAULT_FILES, {"silhouette": extent_m, "height_map": extent_m}, mask,
                               None if height is None else h, None if scan is None else vertices)
    if truth is not None:
        files[TRUTH_FILE] = _truth_bytes(truth, fail)
    _write_atomically(folder, files, overwrite)
    return folder


def _truth_bytes(truth: dict, fail: _Fail) -> bytes:
    if not isinstance(truth, dict):
        raise fail(TRUTH_FILE, None, f"truth must be a dict, got {type(truth).__name__}")
    truth = dict(truth)
    if "params" not in truth:
        raise fail(TRUTH_FILE, "params", "missing required key")
    if isinstance(truth["params"], FabricParams):
        truth["params"] = truth["params"].to_dict()
    truth = {key: _jsonable(value, fail, TRUTH_FILE, key) for key, value in truth.items()}
    for key in ("params", "effects", "mesh"):
        if key in truth and not isinstance(truth[key], dict):
            raise fail(TRUTH_FILE, key, f"must be a dict, got {truth[key]!r}")
    try:
        FabricParams.from_dict(truth["params"], source="params")
    except ParameterError as e:
        raise fail(TRUTH_FILE, "params", str(e)) from None
    return _dump_json(truth, fail, TRUTH_FILE)


def _write_atomically(folder: Path, files: dict[str, bytes], overwrite: bool) -> None:
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = folder.parent / f".{folder.name}.tmp-{uuid.uuid4().hex[:12]}"
        tmp.mkdir()
    except OSError as e:
        raise MeasurementError(f"{folder}: cannot create the folder ({e.strerror or e})") from None
    old = tmp.with_name(tmp.name + ".old")
    try:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
        if overwrite and folder.is_dir():
            os.rename(folder, old)
            try:
                os.rename(tmp, folder)
            except OSError:
                os.rename(old, folder)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, folder)
    except OSError as e:
        raise MeasurementError(f"{folder}: writing failed, nothing was written "
                               f"({e.strerror or e})") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


__all__ = [
    "FORMAT", "MEASUREMENT_FILE", "TRUTH_FILE", "SPECIMEN_SHAPES", "OBSERVATIONS",
    "MeasurementError", "Measurement", "load_measurement", "load_truth", "write_measurement",
]
