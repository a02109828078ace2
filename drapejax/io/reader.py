"""Reading a measurement folder: ``load_measurement`` and ``load_truth``.

Each file is read as bytes and decoded here (PNG, NPY, PLY/OBJ), so that every failure, a
missing file included, becomes one ``MeasurementError`` naming the folder, file and field;
the loaded arrays are read-only.
"""

from __future__ import annotations

import io
import os
from pathlib import Path, PurePath

import cv2
import numpy as np
import trimesh

from .checks import _height_map, _observations_within_reach, _photo, _read_only, _scan, _silhouette_mask
from .format import MEASUREMENT_FILE, TRUTH_FILE
from .header import _parse_header, _read_json
from .measurement import Measurement, MeasurementError, _Fail

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


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
