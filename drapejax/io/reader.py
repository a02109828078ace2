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


_PLY_FLOAT = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}
_PLY_INDEX = {"int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4"}


def _plain_ply(data: bytes) -> tuple[np.ndarray, np.ndarray | None] | None:
    """(vertices, faces) of a binary little-endian PLY holding only x, y, z and triangles; else None.

    That is the layout ``write_measurement`` writes and trimesh exports, so nearly every scan of a
    measurement folder is read here with NumPy alone; any other file goes to trimesh (an import of
    about a second that a command reading a folder would otherwise always pay).
    """
    end = data.find(b"end_header\n", 0, 4096)
    if not data.startswith(b"ply\n") or end < 0:
        return None
    lines = [ln.split() for ln in data[4:end].decode("ascii", "replace").splitlines()]
    lines = [ln for ln in lines if ln and ln[0] != "comment"]
    if not lines or lines[0] != ["format", "binary_little_endian", "1.0"]:
        return None
    lines = lines[1:]
    if len(lines) < 4 or lines[0][:2] != ["element", "vertex"]:
        return None
    types = [_PLY_FLOAT.get(ln[1]) if len(ln) == 3 and ln[0] == "property" else None for ln in lines[1:4]]
    if [ln[-1] for ln in lines[1:4]] != ["x", "y", "z"] or len(set(types)) != 1 or types[0] is None:
        return None
    n_vert = int(lines[0][2])
    rest = lines[4:]
    n_face, index = 0, None
    if rest:
        face = rest[1] if len(rest) == 2 else []
        if (rest[0][:2] != ["element", "face"] or len(face) != 5 or face[:3] != ["property", "list", "uchar"]
                or face[4] not in ("vertex_indices", "vertex_index")):
            return None
        n_face, index = int(rest[0][2]), _PLY_INDEX.get(face[3])
        if index is None:
            return None
    body = memoryview(data)[end + len(b"end_header\n"):]
    vert_bytes = 3 * np.dtype(types[0]).itemsize * n_vert
    face_dtype = np.dtype([("n", "u1"), ("idx", index or "<i4", (3,))])
    if len(body) != vert_bytes + face_dtype.itemsize * n_face:
        return None
    verts = np.frombuffer(body[:vert_bytes], types[0]).reshape(n_vert, 3).astype(np.float64)
    if index is None:
        return verts, None
    packed = np.frombuffer(body[vert_bytes:], face_dtype)
    if not np.all(packed["n"] == 3):
        return None
    return verts, packed["idx"].astype(np.int64)


def _read_scan(folder: Path, file: str, fail: _Fail):
    data = _read_bytes(folder / file, fail, file, "scan")
    plain = _plain_ply(data) if PurePath(file).suffix.lower() == ".ply" else None
    if plain is not None:
        return _scan(*plain, fail, file)
    import trimesh  # here, not at the top: only scans that _plain_ply cannot read need it

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
