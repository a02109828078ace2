"""Writing a measurement folder: ``write_measurement``.

The inputs pass the reader's checks before anything is written (a folder that was written
loads), and the folder is written atomically: every file into a temporary sibling folder,
then one rename, so that a failure leaves either nothing or the previous folder.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import uuid
from pathlib import Path

import cv2
import numpy as np

from ..material import FabricParams, ParameterError
from .bench import BenchRecord
from .checks import _height_map, _observations_within_reach, _photo, _scan, _silhouette_mask
from .format import DEFAULT_FILES, FORMAT, MEASUREMENT_FILE, RESERVED_KEYS, SPECIMEN_SHAPES, TRUTH_FILE
from .header import _parse_header
from .measurement import MeasurementError, _Fail


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
    bench=(),
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
        bench: bench readings on strips of the same fabric (``io.bench.BenchRecord`` or their
            JSON objects), written under "bench".
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
    if bench:
        raw["bench"] = [r.to_json() if isinstance(r, BenchRecord) else r for r in bench]
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
