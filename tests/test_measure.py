"""``drapejax measure``: a user's files become one measurement folder that loads, or nothing at all.

The drape here is parametric (no simulator): a flat disc and a skirt whose generators bend over
a knee and run down at an angle that varies with azimuth (5 folds), so a scan, a photo and a
silhouette of it are cheap and its true top view is known.
"""

import json

import cv2
import numpy as np
import pytest
import trimesh

from drapejax import summary
from drapejax.cli import main
from drapejax.io import MEASUREMENT_FILE, build_measurement, load_measurement
from drapejax.observe import describe_mesh, height_map, point_cloud_views, silhouette
from drapejax.photo import ArucoMarker, PinholeCamera, render_photo

from helpers import drape_mesh

MARKER = {"dictionary": "DICT_4X4_50", "id": 0, "side_m": 0.04, "center_m": [0.0, 0.0, 0.002]}


@pytest.fixture(scope="module")
def drape():
    return drape_mesh(n_ring=16, n_ang=180, tilt=0.0, disc_rings=6)


@pytest.fixture
def files(tmp_path, drape):
    """The user's files in their own folder; each test writes its measurement into ``tmp_path / "out"``."""
    d = tmp_path / "files"
    d.mkdir()
    v, f = drape
    trimesh.Trimesh(v, f, process=False).export(d / "scan.ply")
    trimesh.Trimesh(v * 1000.0, f, process=False).export(d / "scan_mm.ply")
    trimesh.Trimesh(v, f, process=False).export(d / "scan.stl")
    trimesh.PointCloud(v).export(d / "cloud.ply")
    return d


def _run(capsys, *args):
    rc = main(["measure", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _refused(capsys, tmp_path, *args, names=()):
    """Exit status 2 with one error line naming each of ``names``, and no folder or staging left."""
    rc, out, err = _run(capsys, *args)
    lines = [line for line in err.splitlines() if not line.startswith("[drapejax]")]
    assert rc == 2, (out, err)
    assert len(lines) == 1 and lines[0].startswith("drapejax measure: error: "), err
    assert "Traceback" not in err
    for name in names:
        assert name in lines[0], (name, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["files"], list(tmp_path.iterdir())
    return lines[0]


def test_scan_mesh_round_trips_with_its_rendered_views(capsys, tmp_path, files, drape):
    out = tmp_path / "out"
    rc, text, _ = _run(capsys, "--out", out, "--scan", files / "scan.ply", "--density", "0.21", "--json")
    assert rc == 0
    res = json.loads(text)  # one JSON object, nothing else on stdout
    assert res["observations"] == ["silhouette", "height_map", "scan"]
    assert set(res["files"]) == {MEASUREMENT_FILE, "silhouette.png", "height.npy", "scan.ply"}
    m = load_measurement(out)
    v, f = drape
    np.testing.assert_allclose(m.scan_vertices, v, atol=1e-7)  # the user's PLY holds float32
    np.testing.assert_array_equal(m.scan_faces, f)
    np.testing.assert_array_equal(m.silhouette, silhouette(m.scan_vertices, f, n=256, extent_m=0.16))
    np.testing.assert_array_equal(m.height, height_map(m.scan_vertices, f, n=256, extent_m=0.16))
    np.testing.assert_allclose(m.height, height_map(v, f), atol=1e-7)
    assert (m.test, m.specimen_radius_m, m.disk_radius_m) == ("cusick", 0.15, 0.09)
    assert m.areal_density_kg_m2 == 0.21 and m.warp_angle_deg is None and m.silhouette_extent_m == 0.16
    truth = describe_mesh(v, f)
    assert res["descriptors"]["folds"] == truth["folds"] == 5
    assert res["descriptors"]["dc"] == pytest.approx(truth["dc"], abs=1e-9)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["files", "out"]  # no staging folder left


def test_human_summary_names_the_folder_and_descriptors(capsys, tmp_path, files):
    rc, text, _ = _run(capsys, "--out", tmp_path / "out", "--scan", files / "scan.ply", "--density", "unknown",
                       "--warp-angle-deg", "30")
    assert rc == 0
    first = text.splitlines()[0]
    assert first == f"drapejax measure: wrote {tmp_path / 'out'} (silhouette, height map, scan)"
    for words in ("not weighed", "warp angle              30°", "drape coefficient", "5 (dominant harmonic 5)"):
        assert words in text, (words, text)
    m = load_measurement(tmp_path / "out")
    assert m.areal_density_kg_m2 is None and m.warp_angle_deg == 30.0


def test_stl_mm_scan_and_point_cloud(tmp_path, files, drape):
    v, f = drape
    res = build_measurement(tmp_path / "stl", scan=files / "scan.stl", areal_density_kg_m2=0.2)
    m = load_measurement(tmp_path / "stl")
    assert len(m.scan_vertices) == len(v)  # the STL's triangle soup is merged back into one surface
    np.testing.assert_array_equal(m.silhouette, silhouette(m.scan_vertices, m.scan_faces))
    assert res["descriptors"]["hem_height_mean_mm"] == pytest.approx(describe_mesh(v, f)["hem_height_mean_mm"])
    build_measurement(tmp_path / "mm", scan=files / "scan_mm.ply", scan_unit="mm", areal_density_kg_m2=0.2)
    np.testing.assert_allclose(load_measurement(tmp_path / "mm").scan_vertices, v, atol=1e-12)
    res = build_measurement(tmp_path / "cloud", scan=files / "cloud.ply", areal_density_kg_m2=0.2)
    m = load_measurement(tmp_path / "cloud")
    assert m.scan_faces is None and res["scan"] == {"points": len(v), "faces": 0}
    sil, hgt = point_cloud_views(m.scan_vertices)
    np.testing.assert_array_equal(m.silhouette, sil)
    np.testing.assert_array_equal(m.height, hgt)


def test_silhouette_and_height_files(tmp_path, files, drape):
    v, f = drape
    sil, hgt = silhouette(v, f, n=128, extent_m=0.2), height_map(v, f, n=128, extent_m=0.2)
    cv2.imwrite(str(files / "sil.png"), cv2.cvtColor(sil, cv2.COLOR_GRAY2BGR))  # an RGB mask is read as grey
    np.save(files / "h.npy", hgt)
    res = build_measurement(tmp_path / "out", silhouette=files / "sil.png", height=files / "h.npy", extent_m=0.2,
                            test="square", areal_density_kg_m2=None, warp_angle_deg=0.0)
    m = load_measurement(tmp_path / "out")
    np.testing.assert_array_equal(m.silhouette, sil)
    np.testing.assert_array_equal(m.height, hgt)
    assert m.test == "square" and m.silhouette_extent_m == 0.2 and res["sources"]["silhouette"] == "sil.png"


def test_photo_with_marker(capsys, tmp_path, files, drape):
    v, f = drape
    cam = PinholeCamera.looking_at((0, 0, 0), 1.0, f_px=900, image_size=(960, 720), tilt_deg=8, yaw_deg=30)
    img = render_photo(v, f, camera=cam, marker=ArucoMarker.from_dict(MARKER), background="green", noise_std=2.0)
    cv2.imwrite(str(files / "photo.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    out = files / "out"  # inside files/, so that _refused's listing of tmp_path holds
    rc, text, err = _run(capsys, "--out", out, "--photo", files / "photo.png", "--marker-side-m", "0.04",
                         "--density", "0.2", "--json")
    assert rc == 0, err
    res = json.loads(text)
    m = load_measurement(out)
    assert res["observations"] == ["photo"] and m.photo_marker["side_m"] == 0.04
    np.testing.assert_array_equal(m.photo, img)
    assert res["descriptors"]["dc"] == pytest.approx(describe_mesh(v, f)["dc"], abs=0.03)
    assert res["descriptors"]["folds"] == 5
    line = _refused(capsys, tmp_path, "--out", tmp_path / "other", "--photo", files / "photo.png",
                    "--marker-side-m", "0.04", "--marker-id", "7", "--density", "0.2",
                    names=("--photo", str(files / "photo.png"), "marker id 7"))
    assert "measure-" not in line  # the staging folder is not named
    _refused(capsys, tmp_path, "--out", tmp_path / "other", "--photo", files / "photo.png", "--scan",
             files / "scan.ply", "--marker-side-m", "0.04", "--marker-id", "7", "--density", "0.2",
             names=("--photo", "marker id 7"))  # checked although the scan's views need no photo
    _refused(capsys, tmp_path, "--out", tmp_path / "other", "--photo", files / "photo.png", "--density", "0.2",
             names=("--marker-side-m",))
    _refused(capsys, tmp_path, "--out", tmp_path / "other", "--photo", files / "photo.png", "--marker-side-m", "40",
             "--density", "0.2", names=("--marker-side-m", "metres"))


@pytest.mark.parametrize("args, names", [
    (["--scan", "{files}/missing.ply", "--density", "0.2"], ("--scan", "missing.ply", "not found")),
    (["--scan", "{files}/garbage.ply", "--density", "0.2"], ("--scan", "garbage.ply", "trimesh cannot read it")),
    (["--scan", "{files}/scan.ply", "--density", "210"], ("--density 210", "areal_density_kg_m2", "g/m²")),
    (["--scan", "{files}/scan.ply", "--density", "-0.2"], ("--density -0.2", "positive")),
    (["--scan", "{files}/scan.ply", "--density", "heavy"], ("--density heavy", "unknown")),
    (["--scan", "{files}/scan_mm.ply", "--density", "0.2"], ("--scan", "scan_mm.ply", "millimetres", "--scan-unit")),
    (["--scan", "{files}/scan.ply", "--density", "0.2", "--disk-radius-m", "90"], ("--disk-radius-m",)),
    (["--density", "0.2"], ("at least one observation",)),
    (["--silhouette", "{files}/scan.ply", "--density", "0.2", "--extent-m", "0.16"], ("--silhouette", "readable")),
    (["--silhouette", "{files}/scan.ply", "--density", "0.2"], ("--extent-m",)),
    (["--height", "{files}/scan.ply", "--density", "0.2", "--extent-m", "0.16"], ("--height", "scan.ply", ".npy")),
    (["--scan", "{files}/scan.ply", "--density", "0.2", "--marker-side-m", "0.04"], ("--marker-side-m", "--photo")),
])
def test_refusals_name_the_option_and_leave_nothing(capsys, tmp_path, files, args, names):
    (files / "garbage.ply").write_bytes(b"ply\nthis is not a mesh\n")
    _refused(capsys, tmp_path, "--out", tmp_path / "out", *(a.format(files=files) for a in args), names=names)


def test_existing_folder_needs_overwrite_and_survives_a_failed_overwrite(capsys, tmp_path, files):
    out = tmp_path / "files" / "out"  # inside files/, so that _refused's listing of tmp_path holds
    assert _run(capsys, "--out", out, "--scan", files / "scan.ply", "--density", "0.2")[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    _refused(capsys, tmp_path, "--out", out, "--scan", files / "scan.ply", "--density", "0.3",
             names=("--out", str(out), "--overwrite"))
    _refused(capsys, tmp_path, "--out", out, "--scan", files / "scan_mm.ply", "--density", "0.3", "--overwrite",
             names=("--scan",))
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in files.iterdir() if p.name.startswith(".")) == []
    assert _run(capsys, "--out", out, "--scan", files / "scan.ply", "--density", "0.3", "--overwrite")[0] == 0
    assert load_measurement(out).areal_density_kg_m2 == 0.3
    (files / "notes").mkdir()
    (files / "notes" / "keep.txt").write_text("mine")
    _refused(capsys, tmp_path, "--out", files / "notes", "--scan", files / "scan.ply", "--density", "0.3",
             "--overwrite", names=("--out", "not a measurement folder"))
    assert (files / "notes" / "keep.txt").read_text() == "mine"


def test_real_scan(shared_data, tmp_path):
    src = shared_data / "real_cusick" / "bdp_f01_sample_10_capture_1"
    if not src.is_dir():
        pytest.skip(f"{src} not found")
    res = build_measurement(tmp_path / "out", scan=src / "scan.ply", areal_density_kg_m2=0.059)
    m, real = load_measurement(tmp_path / "out"), load_measurement(src)
    np.testing.assert_allclose(m.scan_vertices, real.scan_vertices)
    np.testing.assert_array_equal(m.silhouette, silhouette(real.scan_vertices, real.scan_faces))
    assert 0.3 < res["descriptors"]["dc"] < 0.8 and res["descriptors"]["folds"] >= 5


def test_summary_tolerates_missing_keys():
    assert summary.measure({}).startswith("drapejax measure: wrote the folder")
    text = summary.summarize("measure", {"out": "F", "observations": ["photo"], "areal_density_kg_m2": 0.2,
                                         "descriptors": {"dc": 0.5, "folds": 6}})
    assert text.splitlines()[0] == "drapejax measure: wrote F (photo)" and "200 g/m²" in text and "6" in text
