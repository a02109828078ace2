"""Measurement folder reader and writer (spec/measurement-format.md)."""

import io
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from drapejax.io import (FORMAT, Measurement, MeasurementError, load_measurement, load_truth,
                         write_measurement)
from drapejax.material import example_params

N = 32
EXTENT = 0.16


def _grid(n=N, extent=EXTENT):
    """World x, y of pixel centres: column grows with +x, row grows with -y."""
    c = -extent + (np.arange(n) + 0.5) * 2 * extent / n
    return np.meshgrid(c, -c)


def _drape(n=N):
    """An asymmetric drape-like mask and float32 height map (NaN off the fabric)."""
    x, y = _grid(n)
    r, phi = np.hypot(x, y), np.arctan2(y, x)
    fabric = r < 0.11 + 0.02 * np.cos(5 * phi) + 0.015 * (x > 0.05)
    height = np.where(fabric, -0.4 * np.maximum(r - 0.09, 0.0), np.nan).astype(np.float32)
    return fabric, height


def _scan(rng):
    u, v = np.meshgrid(np.linspace(-0.1, 0.1, 5), np.linspace(-0.1, 0.1, 5))
    vertices = np.stack([u.ravel(), v.ravel(), rng.uniform(-0.05, 0, 25)], 1)
    vertices[:, :2] += rng.normal(0, 1e-3, (25, 2))
    idx = np.arange(25).reshape(5, 5)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return vertices, faces


MARKER = {"dictionary": "DICT_4X4_50", "id": 7, "side_m": 0.04, "center_m": [0.0, 0.0, 0.002]}


def _full_kwargs(seed=0):
    rng = np.random.default_rng(seed)
    fabric, height = _drape()
    return dict(
        test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09, areal_density_kg_m2=0.21,
        warp_angle_deg=12.5,
        tag={"category": "Woven", "composition": {"Cotton": 0.98, "Spandex / Elastane": 0.02},
             "density_gsm": 210},
        silhouette=fabric, extent_m=EXTENT, height=height,
        photo=rng.integers(0, 256, (24, 40, 3), dtype=np.uint8), photo_marker=MARKER,
        scan=_scan(rng),
        truth={"params": example_params("mid").to_dict(), "effects": {"friction": 0.3},
               "mesh": {"spacing_m": 0.01}},
        extra={"source": {"generator": "test", "seed": seed}},
    )


# ---------------------------------------------------------------------------------------
# real data


def test_every_real_cusick_folder_loads(shared_data):
    folders = sorted((shared_data / "real_cusick").iterdir())
    assert len(folders) == 48
    known = {1: 0.059, 2: 0.192, 4: 0.114}
    for folder in folders:
        m = load_measurement(folder)
        fabric = int(folder.name.split("_")[1][1:])
        assert m.test == "cusick" and m.specimen_radius_m == 0.15 and m.disk_radius_m == 0.09
        assert m.areal_density_kg_m2 == known.get(fabric)
        assert m.warp_angle_deg is None and m.tag is None
        assert m.extra["source"]["fabric"] == fabric
        assert m.silhouette.shape == m.height.shape == (256, 256)
        assert m.silhouette_extent_m == m.height_extent_m == 0.16
        assert set(np.unique(m.silhouette)) == {0, 255}
        assert m.height.dtype == np.float32 and not m.has_photo
        assert m.scan_vertices.dtype == np.float64 and m.scan_faces.shape[1] == 3
        # Geometry in the spec's frame: the fabric lies flat on the disk top (z = 0), lies no
        # farther out than the specimen radius (real scans stretch up to 2%) and hangs by less
        # than the 6 cm overhang (one scan, f08 sample 2, has a fold 2 cm above the disk).
        x, y = _grid(256, 0.16)
        r = np.hypot(x, y)
        pixel = 2 * 0.16 / 256
        assert np.all(m.silhouette[r < 0.09 - pixel] == 255)
        assert np.all(m.silhouette[r > 1.02 * 0.15 + pixel] == 0)
        assert np.all(np.abs(m.height[r < 0.08]) < 1e-4)
        assert -0.061 < np.nanmin(m.height) and np.nanmax(m.height) < 0.025
        # The scan's vertices project onto the silhouette with the spec's pixel convention.
        v = m.scan_vertices
        col = np.floor((v[:, 0] + 0.16) / pixel).astype(int)
        row = np.floor((0.16 - v[:, 1]) / pixel).astype(int)
        assert np.mean(m.silhouette[row, col] == 255) > 0.97
        with pytest.raises(ValueError):
            m.height[0, 0] = 1.0


# ---------------------------------------------------------------------------------------
# writer


def test_write_read_round_trip(tmp_path):
    kw = _full_kwargs()
    folder = write_measurement(tmp_path / "m", **kw)
    m = load_measurement(folder)
    assert isinstance(m, Measurement) and m.path == folder
    assert (m.test, m.specimen_radius_m, m.disk_radius_m) == ("cusick", 0.15, 0.09)
    assert m.areal_density_kg_m2 == 0.21 and m.warp_angle_deg == 12.5
    assert m.tag == kw["tag"]
    np.testing.assert_array_equal(m.silhouette, np.where(kw["silhouette"], 255, 0))
    assert m.silhouette.dtype == np.uint8
    np.testing.assert_array_equal(m.height, kw["height"])
    assert m.silhouette_extent_m == m.height_extent_m == EXTENT
    np.testing.assert_array_equal(m.photo, kw["photo"])
    assert m.photo_marker == {**MARKER, "center_m": tuple(MARKER["center_m"])}
    np.testing.assert_array_equal(m.scan_vertices, kw["scan"][0])
    np.testing.assert_array_equal(m.scan_faces, kw["scan"][1])
    assert m.extra["source"] == kw["extra"]["source"]
    assert load_truth(folder) == kw["truth"]


def test_round_trip_square_point_cloud_unknowns(tmp_path):
    rng = np.random.default_rng(1)
    points = rng.uniform([-0.1, -0.1, -0.1], [0.1, 0.1, 0.0], (50, 3))  # below the disc top, as a drape hangs
    folder = write_measurement(tmp_path / "sq", test="square", specimen_radius_m=0.15,
                               disk_radius_m=0.09, areal_density_kg_m2=None, warp_angle_deg=None,
                               scan=(points, None))
    raw = json.loads((folder / "measurement.json").read_text())
    assert raw["specimen"] == {"shape": "square", "half_side_m": 0.15}
    assert raw["areal_density_kg_m2"] is None and raw["warp_angle_deg"] is None
    m = load_measurement(folder)
    assert m.test == "square" and m.areal_density_kg_m2 is None and m.warp_angle_deg is None
    np.testing.assert_array_equal(m.scan_vertices, points)
    assert m.scan_faces is None and not m.has_silhouette and load_truth(folder) is None


def test_written_files_follow_the_spec(tmp_path):
    kw = _full_kwargs()
    folder = write_measurement(tmp_path / "m", **kw)
    raw = json.loads((folder / "measurement.json").read_text())
    assert raw["format"] == FORMAT == "drapejax-measurement/1"
    assert raw["specimen"] == {"shape": "circle", "radius_m": 0.15}
    assert raw["support"] == {"disk_radius_m": 0.09}
    assert raw["silhouette"] == {"file": "silhouette.png", "extent_m": EXTENT}
    assert raw["height_map"] == {"file": "height.npy", "extent_m": EXTENT}
    assert raw["photo"] == {"file": "photo.png", "marker": MARKER}
    assert raw["scan"] == {"file": "scan.ply"} and raw["source"] == kw["extra"]["source"]
    sil = cv2.imread(str(folder / "silhouette.png"), cv2.IMREAD_UNCHANGED)
    assert sil.dtype == np.uint8 and sil.shape == (N, N)
    np.testing.assert_array_equal(sil, np.where(kw["silhouette"], 255, 0))
    h = np.load(folder / "height.npy")
    assert h.dtype == np.float32 and h.shape == (N, N)
    # PNG stores RGB; OpenCV hands it back as BGR.
    np.testing.assert_array_equal(cv2.imread(str(folder / "photo.png"))[..., ::-1], kw["photo"])
    mesh = trimesh.load(folder / "scan.ply", process=False)
    np.testing.assert_array_equal(mesh.vertices, kw["scan"][0])
    truth = json.loads((folder / "truth.json").read_text())
    assert set(truth) == {"params", "effects", "mesh"}


def test_silhouette_threshold_and_warp_default(tmp_path):
    fabric, height = _drape()
    folder = write_measurement(tmp_path / "m", test="cusick", specimen_radius_m=0.15,
                               disk_radius_m=0.09, areal_density_kg_m2=0.2,
                               silhouette=fabric, height=height)
    # Near-binary grey levels and anti-aliased edge pixels (128 is fabric, 127 is not).
    soft = np.where(fabric, 240, 15).astype(np.uint8)
    inner_edge = fabric & ~np.roll(fabric, 1, axis=1)
    outer_edge = ~fabric & np.roll(fabric, 1, axis=1)
    soft[inner_edge], soft[outer_edge] = 128, 127
    cv2.imwrite(str(folder / "silhouette.png"), soft)
    raw = json.loads((folder / "measurement.json").read_text())
    del raw["warp_angle_deg"]
    (folder / "measurement.json").write_text(json.dumps(raw))
    m = load_measurement(folder)
    np.testing.assert_array_equal(m.silhouette, np.where(fabric, 255, 0))
    assert m.warp_angle_deg == 0.0


def test_obj_scan_is_read(tmp_path):
    vertices, faces = _scan(np.random.default_rng(3))
    folder = write_measurement(tmp_path / "m", test="cusick", specimen_radius_m=0.15,
                               disk_radius_m=0.09, areal_density_kg_m2=0.2, scan=(vertices, faces))
    trimesh.Trimesh(vertices, faces, process=False).export(folder / "scan.obj")
    raw = json.loads((folder / "measurement.json").read_text())
    raw["scan"]["file"] = "scan.obj"
    (folder / "measurement.json").write_text(json.dumps(raw))
    m = load_measurement(folder)
    np.testing.assert_allclose(m.scan_vertices, vertices, atol=1e-7)
    np.testing.assert_array_equal(m.scan_faces, faces)


def test_plain_ply_reader_equals_trimesh(shared_data):
    """The NumPy reader of plain binary PLY scans gives trimesh's arrays (values and dtypes) on every
    real scan and on the writer's own files, and hands anything else (ASCII, truncated, extra
    properties) back to trimesh."""
    from drapejax.io.reader import _plain_ply
    from drapejax.io.writer import _ply_bytes

    files = [p.read_bytes() for p in sorted((shared_data / "real_cusick").glob("*/scan.ply"))]
    vertices, faces = _scan(np.random.default_rng(4))
    files += [_ply_bytes(vertices, faces), _ply_bytes(vertices, None)]
    for data in files:
        plain = _plain_ply(data)
        assert plain is not None
        ref = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
        np.testing.assert_array_equal(plain[0], ref.vertices)
        assert plain[0].dtype == ref.vertices.dtype
        if isinstance(ref, trimesh.Trimesh):
            np.testing.assert_array_equal(plain[1], ref.faces)
            assert plain[1].dtype == ref.faces.dtype
        else:
            assert plain[1] is None
    assert len(files) > 10
    data = files[0]
    extra = data.replace(b"property float z\n", b"property float z\nproperty uchar red\n", 1)
    for other in (data[:-5], extra, _ply_header(3, 0).encode() + b"0 0 0\n1 0 0\n0 1 0\n"):
        assert _plain_ply(other) is None


def test_overwrite(tmp_path):
    kw = _full_kwargs()
    folder = write_measurement(tmp_path / "m", **kw)
    with pytest.raises(MeasurementError, match="already exists"):
        write_measurement(folder, **kw)
    assert (folder / "photo.png").exists()
    kw.update(photo=None, photo_marker=None, warp_angle_deg=3.0)
    write_measurement(folder, overwrite=True, **kw)
    assert not (folder / "photo.png").exists()
    assert load_measurement(folder).warp_angle_deg == 3.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]


def _invalid_inputs():
    fabric, height = _drape()
    holed = height.copy()
    holed[N // 2, N // 2] = np.nan
    bad_scan = _scan(np.random.default_rng(0))[0].copy()
    bad_scan[3, 2] = np.nan
    bad_params = example_params("mid").to_dict()
    bad_params["bend_k1_warp"] = 13.8  # µN·m given as SI
    return [
        ("height", dict(height=holed)),
        ("areal_density_kg_m2", dict(areal_density_kg_m2=-0.2)),
        ("areal_density_kg_m2", dict(areal_density_kg_m2=float("nan"))),
        ("test", dict(test="drop")),
        ("specimen.radius_m", dict(specimen_radius_m=0.0)),
        ("disk_radius_m", dict(disk_radius_m=0.2)),
        ("warp_angle_deg", dict(warp_angle_deg="north")),
        ("silhouette", dict(silhouette=np.dstack([fabric] * 3))),
        ("silhouette", dict(silhouette=fabric.astype(np.uint8))),
        ("extent_m", dict(extent_m=-0.16)),
        ("marker", dict(photo_marker=None)),
        ("marker", dict(photo_marker={**MARKER, "dictionary": "DICT_9X9_1"})),
        ("marker", dict(photo_marker={**MARKER, "side_m": 40.0})),  # mm
        ("marker", dict(photo_marker={**MARKER, "center_m": [0.3, 0.0, 0.002]})),  # off the clamp
        ("center_m", dict(photo_marker={**MARKER, "center_m": [0.0, 0.0, 2.0]})),
        ("photo", dict(photo=np.zeros((10, 10), np.uint8))),
        ("scan", dict(scan=(bad_scan, None))),
        ("scan", dict(scan=(bad_scan[:, :2], None))),
        ("specimen.radius_m", dict(specimen_radius_m=150.0, disk_radius_m=90.0)),
        ("areal_density_kg_m2", dict(areal_density_kg_m2=210.0)),
        ("scan", dict(scan=(1000.0 * _scan(np.random.default_rng(0))[0], _scan(np.random.default_rng(0))[1]))),
        ("height_map", dict(height=1000.0 * height)),
        ("silhouette", dict(extent_m=160.0)),
        ("tag", dict(tag={"density_gsm": float("inf")})),
        ("tag", dict(tag={"when": object()})),
        ("source", dict(extra={"test": "square"})),
        ("params", dict(truth={"params": bad_params})),
        ("params", dict(truth={"effects": {}})),
    ]


@pytest.mark.parametrize("token, change", _invalid_inputs(), ids=lambda x: x if isinstance(x, str) else "")
def test_writer_rejects_invalid_input_and_leaves_nothing(tmp_path, token, change):
    kw = {**_full_kwargs(), **change}
    target = tmp_path / "out" / "m"
    with pytest.raises(MeasurementError) as err:
        write_measurement(target, **kw)
    msg = str(err.value)
    assert str(target) in msg
    assert token in msg or (token == "source" and "'test'" in msg)
    assert not target.exists()
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []


def _cone_scan(n=4000, seed=0):
    """Points of a cone-shaped drape in the spec's frame: flat on the 9 cm disc, the 6 cm skirt
    hanging at 60° below it (reaching 12 cm out, 5.2 cm down)."""
    rng = np.random.default_rng(seed)
    s, phi = 0.15 * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    over = np.maximum(s - 0.09, 0.0)
    r, z = np.minimum(s, 0.09) + 0.5 * over, -np.sqrt(0.75) * over
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


@pytest.mark.parametrize("slip, hint", [
    (lambda v: 1000.0 * v, "millimetres"),
    (lambda v: 100.0 * v, "centimetres"),
    (lambda v: v[:, [0, 2, 1]], "y-up"),
    (lambda v: v * [1, 1, -1], "z up"),  # upside down: the skirt stands above the disc
    (lambda v: v + [0.3, 0.2, 0.0], "origin at the centre of the disc top"),
])
def test_scan_out_of_the_specimens_reach_is_refused_with_the_likely_slip(tmp_path, slip, hint):
    """Where a 15 cm specimen on the disc cannot be (beyond 1.5x its radius from the disc centre,
    or more than 1.5x its overhang above the disc top) a scan is in the wrong units or frame; it
    is refused by name instead of being fitted as a drape, and the correct frame loads."""
    kw = dict(test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09, areal_density_kg_m2=0.2)
    v = _cone_scan()
    write_measurement(tmp_path / "ok", scan=(v, None), **kw)
    assert load_measurement(tmp_path / "ok").has_scan
    bad = slip(v)
    with pytest.raises(MeasurementError, match=hint) as err:
        write_measurement(tmp_path / "w", scan=(bad, None), **kw)
    assert "scan" in str(err.value) and not (tmp_path / "w").exists()
    ply = tmp_path / "ok" / "scan.ply"
    trimesh.PointCloud(bad).export(ply)
    with pytest.raises(MeasurementError, match=hint):
        load_measurement(tmp_path / "ok")


def test_a_few_stray_scan_points_are_tolerated(tmp_path):
    """Scanner outliers (here 0.5% of the points, 1 m away) do not make a scan unreadable."""
    v = _cone_scan()
    v[:20] = [1.0, 0.0, -0.5]
    folder = write_measurement(tmp_path / "m", test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                               areal_density_kg_m2=None, scan=(v, None))
    assert len(load_measurement(folder).scan_vertices) == len(v)


def test_writer_is_atomic_when_writing_fails(tmp_path, monkeypatch):
    kw = _full_kwargs()
    folder = write_measurement(tmp_path / "m", **kw)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    real_write = Path.write_bytes

    def failing_write(self, data):
        if self.name == "scan.ply":
            raise OSError(28, "No space left on device")
        return real_write(self, data)

    monkeypatch.setattr(Path, "write_bytes", failing_write)
    with pytest.raises(MeasurementError, match="nothing was written"):
        write_measurement(tmp_path / "new", **kw)
    with pytest.raises(MeasurementError, match="nothing was written"):
        write_measurement(folder, overwrite=True, **{**kw, "warp_angle_deg": 1.0})
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_load_truth_errors(tmp_path):
    with pytest.raises(MeasurementError, match="not found"):
        load_truth(tmp_path / "nope")
    folder = write_measurement(tmp_path / "m", **_full_kwargs())
    (folder / "truth.json").write_text("{\"params\": [1, 2]}")
    with pytest.raises(MeasurementError, match=r"truth\.json field 'params'"):
        load_truth(folder)
    (folder / "truth.json").write_text("{\"params\": ")
    with pytest.raises(MeasurementError, match=r"truth\.json: invalid JSON"):
        load_truth(folder)


# ---------------------------------------------------------------------------------------
# corrupted folders


def _edit_json(key_path, value=None, delete=False):
    """Mutation that sets (or deletes) a key of measurement.json, e.g. ("specimen", "radius_m")."""
    def mutate(folder, rng):
        path = folder / "measurement.json"
        raw = json.loads(path.read_text())
        node = raw
        for k in key_path[:-1]:
            node = node[k]
        if delete:
            del node[key_path[-1]]
        else:
            node[key_path[-1]] = value
        path.write_text(json.dumps(raw))
    return mutate


def _replace_text(old, new):
    def mutate(folder, rng):
        path = folder / "measurement.json"
        text = path.read_text()
        assert old in text
        path.write_text(text.replace(old, new, 1))
    return mutate


def _delete(name):
    def mutate(folder, rng):
        (folder / name).unlink()
    return mutate


def _truncate(name):
    def mutate(folder, rng):
        path = folder / name
        data = path.read_bytes()
        path.write_bytes(data[: int(rng.integers(0, len(data) // 2))])
    return mutate


def _garbage(name):
    def mutate(folder, rng):
        (folder / name).write_bytes(rng.bytes(int(rng.integers(1, 400))))
    return mutate


def _png(name, make):
    def mutate(folder, rng):
        ok, buf = cv2.imencode(".png", make(rng))
        assert ok
        (folder / name).write_bytes(buf.tobytes())
    return mutate


def _npy(make):
    def mutate(folder, rng):
        np.save(folder / "height.npy", make(folder, rng), allow_pickle=True)
    return mutate


def _height_edit(edit):
    def make(folder, rng):
        h = np.load(folder / "height.npy")
        fabric = np.argwhere(~np.isnan(h))
        empty = np.argwhere(np.isnan(h))
        edit(h, fabric[rng.integers(len(fabric))], empty[rng.integers(len(empty))])
        return h
    return make


def _set(value, where):
    def edit(h, on_fabric, off_fabric):
        h[tuple(on_fabric if where == "fabric" else off_fabric)] = value
    return edit


def _npz(folder, rng):
    buf = io.BytesIO()
    np.savez(buf, h=np.load(folder / "height.npy"))
    (folder / "height.npy").write_bytes(buf.getvalue())


def _ply(text):
    def mutate(folder, rng):
        (folder / "scan.ply").write_text(text)
    return mutate


def _ply_header(nv, nf):
    return ("ply\nformat ascii 1.0\n" + f"element vertex {nv}\n"
            + "property double x\nproperty double y\nproperty double z\n"
            + (f"element face {nf}\nproperty list uchar int vertex_indices\n" if nf else "")
            + "end_header\n")


def _into_dir(name):
    def mutate(folder, rng):
        (folder / name).unlink()
        (folder / name).mkdir()
    return mutate


def _remove_folder(folder, rng):
    shutil.rmtree(folder)


def _grey(shape, dtype=np.uint8, value=255):
    return lambda rng: np.full(shape, value, dtype)


MUTATIONS = [
    ("folder", _remove_folder),
    *[(name, _delete(name)) for name in
      ("measurement.json", "silhouette.png", "height.npy", "photo.png", "scan.ply")],
    ("measurement.json", _truncate("measurement.json")),
    ("measurement.json", _garbage("measurement.json")),
    ("measurement.json", _replace_text("{", "{\xff")),
    ("measurement.json", lambda f, rng: (f / "measurement.json").write_bytes(b"{\"format\": \xc3\x28}")),
    ("measurement.json", lambda f, rng: (f / "measurement.json").write_text("[1, 2, 3]")),
    ("measurement.json", lambda f, rng: (f / "measurement.json").write_text("null")),
    ("measurement.json", lambda f, rng: (f / "measurement.json").write_text("")),
    ("measurement.json", _into_dir("measurement.json")),
    ("invalid JSON", _replace_text("\"areal_density_kg_m2\": 0.21", "\"areal_density_kg_m2\": NaN")),
    ("areal_density_kg_m2", _replace_text("\"areal_density_kg_m2\": 0.21", "\"areal_density_kg_m2\": 1e999")),
    *[(key, _edit_json((key,), delete=True)) for key in
      ("format", "test", "specimen", "support", "areal_density_kg_m2")],
    ("silhouette/height_map/photo/scan", lambda f, rng: [
        _edit_json((k,), delete=True)(f, rng) for k in ("silhouette", "height_map", "photo", "scan")]),
    *[("format", _edit_json(("format",), v)) for v in ("drapejax-measurement/2", 1, None, "")],
    *[("test", _edit_json(("test",), v)) for v in ("cusik", "", 3, None, ["cusick"])],
    ("specimen.shape", _edit_json(("test",), "square")),
    ("specimen.shape", _edit_json(("specimen", "shape"), "triangle")),
    ("specimen.shape", _edit_json(("specimen", "shape"), delete=True)),
    *[("specimen.radius_m", _edit_json(("specimen", "radius_m"), v)) for v in
      (-0.15, 0, "0.15", True, None, [0.15])],
    ("specimen.radius_m", _edit_json(("specimen", "radius_m"), delete=True)),
    *[("specimen", _edit_json(("specimen",), v)) for v in ([0.15], "circle", None)],
    *[("support.disk_radius_m", _edit_json(("support", "disk_radius_m"), v)) for v in
      (-0.09, 0.0, 0.15, 0.2, "0.09", False, None)],
    ("support.disk_radius_m", _edit_json(("support", "disk_radius_m"), delete=True)),
    *[("support", _edit_json(("support",), v)) for v in (0.09, [], None)],
    *[("areal_density_kg_m2", _edit_json(("areal_density_kg_m2",), v)) for v in
      (0, -0.21, "0.21", True, [0.21], {"value": 0.21})],
    *[("warp_angle_deg", _edit_json(("warp_angle_deg",), v)) for v in ("north", [0], True, {})],
    *[("tag", _edit_json(("tag",), v)) for v in ("denim", 3, [])],
    *[(key, _edit_json((key,), v)) for key in ("silhouette", "height_map", "photo", "scan")
      for v in ("file.png", 1, [])],
    *[(f"{key}.file", _edit_json((key, "file"), v)) for key in ("silhouette", "height_map", "photo", "scan")
      for v in (None, 3, "", "/etc/passwd", "../x.png")],
    ("nothere.png", _edit_json(("silhouette", "file"), "nothere.png")),
    ("nothere.ply", _edit_json(("scan", "file"), "nothere.ply")),
    ("scan.file", _edit_json(("scan", "file"), "scan.stl")),
    *[(f"{key}.extent_m", _edit_json((key, "extent_m"), v)) for key in ("silhouette", "height_map")
      for v in (-0.16, 0, "0.16", None)],
    *[(f"{key}.extent_m", _edit_json((key, "extent_m"), delete=True)) for key in ("silhouette", "height_map")],
    ("height_map.extent_m", _edit_json(("height_map", "extent_m"), 0.2)),
    ("photo.marker", _edit_json(("photo", "marker"), delete=True)),
    ("photo.marker", _edit_json(("photo", "marker"), "DICT_4X4_50")),
    *[("photo.marker.dictionary", _edit_json(("photo", "marker", "dictionary"), v)) for v in
      ("DICT_FOO", "getPredefinedDictionary", 0, None)],
    *[("photo.marker.id", _edit_json(("photo", "marker", "id"), v)) for v in (-1, 50, 1.5, "7", True)],
    *[("photo.marker.side_m", _edit_json(("photo", "marker", "side_m"), v)) for v in (0, -0.04, "4 cm")],
    *[("photo.marker.center_m", _edit_json(("photo", "marker", "center_m"), v)) for v in
      ([0, 0], [0, 0, "z"], "origin", None)],
    *[(name, _into_dir(name)) for name in ("silhouette.png", "height.npy", "photo.png", "scan.ply")],
    *[(name, _garbage(name)) for name in ("silhouette.png", "height.npy", "photo.png", "scan.ply")],
    *[(name, _truncate(name)) for name in ("silhouette.png", "height.npy", "photo.png", "scan.ply")],
    ("silhouette", _png("silhouette.png", _grey((N, N, 3)))),
    ("silhouette", _png("silhouette.png", _grey((N, N + 4)))),
    ("height", _png("silhouette.png", lambda rng: np.where(np.pad(_drape()[0], 4), 255, 0).astype(np.uint8))),
    ("silhouette", _png("silhouette.png", _grey((N, N), np.uint16, 60000))),
    ("silhouette", _png("silhouette.png", lambda rng: rng.integers(0, 256, (N, N), dtype=np.uint8))),
    ("silhouette", _png("silhouette.png", lambda rng: _drape()[0].astype(np.uint8))),
    ("silhouette", lambda f, rng: (f / "silhouette.png").write_bytes(
        cv2.imencode(".jpg", np.where(_drape()[0], 255, 0).astype(np.uint8))[1].tobytes())),
    ("height", _npy(_height_edit(_set(np.nan, "fabric")))),
    ("height", _npy(_height_edit(_set(np.inf, "fabric")))),
    ("height", _npy(_height_edit(_set(-np.inf, "empty")))),
    ("height", _npy(_height_edit(_set(-0.01, "empty")))),
    ("height", _npy(lambda f, rng: np.load(f / "height.npy")[:, :-1])),
    ("height", _npy(lambda f, rng: np.load(f / "height.npy")[None])),
    ("height", _npy(lambda f, rng: np.load(f / "height.npy").ravel())),
    ("height", _npy(lambda f, rng: np.nan_to_num(np.load(f / "height.npy"), nan=-1).astype(np.int32))),
    ("height", _npy(lambda f, rng: np.array([{"z": 0.0}], dtype=object))),
    ("height", _npy(lambda f, rng: np.pad(np.load(f / "height.npy"), 2, constant_values=np.nan))),
    ("height", _npy(lambda f, rng: np.full((N, N), np.nan, np.float32))),
    ("height", _npz),
    ("photo", _png("photo.png", _grey((24, 40)))),
    ("photo", _png("photo.png", _grey((24, 40, 4)))),
    ("photo", _png("photo.png", _grey((24, 40, 3), np.uint16, 1000))),
    ("scan", _ply(_ply_header(3, 1) + "0 0 0\n1 0 0\n0 1 nan\n3 0 1 2\n")),
    ("scan", _ply(_ply_header(3, 1) + "0 0 0\n1 0 0\n0 1 inf\n3 0 1 2\n")),
    ("scan", _ply(_ply_header(3, 1) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")),
    ("scan", _ply(_ply_header(3, 1) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 -2\n")),
    ("scan", _ply(_ply_header(0, 0))),
    ("scan", _ply("")),
    ("scan", _ply("ply\nformat ascii 1.0\nend_header\n")),
]


@pytest.fixture(scope="module")
def valid_folder(tmp_path_factory):
    folder = write_measurement(tmp_path_factory.mktemp("valid") / "m", **_full_kwargs())
    m = load_measurement(folder)
    assert m.has_silhouette and m.has_height and m.has_photo and m.has_scan
    return folder


def test_corrupted_folders_raise_measurement_error(valid_folder, tmp_path):
    rng = np.random.default_rng(2024)
    order = list(rng.permutation(len(MUTATIONS)))
    order += list(rng.integers(0, len(MUTATIONS), 200 - len(order)))
    assert len(order) == 200
    failures = []
    for i, k in enumerate(order):
        token, mutate = MUTATIONS[k]
        folder = tmp_path / f"c{i:03d}"
        shutil.copytree(valid_folder, folder)
        mutate(folder, rng)
        try:
            load_measurement(folder)
        except MeasurementError as e:
            msg = str(e)
            if str(folder) not in msg or token not in msg:
                failures.append((k, token, f"message lacks folder or {token!r}: {msg}"))
        except Exception as e:  # any other type is a failure, reported below
            failures.append((k, token, f"{type(e).__name__}: {e}"))
        else:
            failures.append((k, token, "loaded without error"))
    assert failures == []
