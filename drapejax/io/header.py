"""The header, ``measurement.json``: strict JSON reading and validation of its keys and values.

``_parse_header`` checks the test, specimen, support, density, warp angle, tag and the
observation entries (file names inside the folder, grid extents, the photo's marker on the top
clamp) and returns the normalised fields; the reader applies it to the file, the writer to the
object it is about to write. ``_read_json`` (also used for ``truth.json``) refuses what is not
standard JSON, NaN and infinity included.
"""

from __future__ import annotations

import json
import math
from pathlib import Path, PurePath

import cv2

from .format import (FORMAT, MAX_AREAL_DENSITY_KG_M2, MAX_SPECIMEN_M, OBSERVATIONS, REACH_FACTOR, SPECIMEN_SHAPES,
                     _circumradius)
from .bench import BENCH_KEY, _parse_bench
from .measurement import _Fail

_SCAN_SUFFIXES = (".ply", ".obj")


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
    bench = _parse_bench(raw.get(BENCH_KEY), fail)
    return dict(test=test, specimen_radius_m=radius, disk_radius_m=disk,
                areal_density_kg_m2=density, warp_angle_deg=warp, tag=tag, entries=entries, bench=bench)


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
