"""Photo → silhouette: synthetic photos of a parametric drape are rectified to its true top view.

The drape is built here without the simulator: a flat disc (r ≤ 9 cm) and a skirt whose
radial generators bend over a 1.5 cm knee and then run straight down at an angle that
varies with azimuth (5 folds plus a one-lobe asymmetry, so a 180° turn changes the shape).
Its true silhouette is the xy-projection of its triangles rasterised on the spec grid.
"""

import dataclasses
import json

import cv2
import numpy as np
import pytest

from drapejax.photo import (
    ArucoMarker, PhotoError, PinholeCamera, estimate_camera_matrix, detect_marker, read_photo,
    rectify_photo, render_photo,
)

from helpers import R_DISK, R_SPEC, drape_mesh

N, EXTENT = 256, 0.16
MARKER = ArucoMarker("DICT_4X4_50", 0, 0.04, (0.0, 0.0, 0.002))


def true_silhouette(verts, faces):
    """Orthographic top view on the spec grid (row 0 = +y, pixel centres at -e + (i + ½)·2e/N)."""
    h = 2 * EXTENT / N
    px = np.stack([(verts[:, 0] + EXTENT) / h - 0.5, (EXTENT - verts[:, 1]) / h - 0.5], 1)
    img = np.zeros((N, N), np.uint8)
    for tri in np.round(px * 256).astype(np.int32)[faces]:
        cv2.fillConvexPoly(img, tri, 255, cv2.LINE_8, 8)
    return img


def iou(a, b):
    a, b = a > 0, b > 0
    return (a & b).sum() / (a | b).sum()


def drape_coefficient(sil):
    """Area-based DC = (projected area − disc area) / (specimen area − disc area)."""
    area = (sil > 0).sum() * (2 * EXTENT / N) ** 2
    return (area - np.pi * R_DISK**2) / (np.pi * (R_SPEC**2 - R_DISK**2))


@pytest.fixture(scope="module")
def drape():
    verts, faces = drape_mesh()
    return verts, faces, true_silhouette(verts, faces)


def test_camera_conventions():
    """Straight top view: +x is image right, +y image up; k1 distortion inverts exactly."""
    cam = PinholeCamera.looking_at((0, 0, 0), 1.0, f_px=800, image_size=(960, 720))
    uv = cam.project(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]))
    np.testing.assert_allclose(uv[0], [479.5, 359.5])
    np.testing.assert_allclose(uv[1] - uv[0], [80.0, 0.0], atol=1e-9)  # f · x / distance
    np.testing.assert_allclose(uv[2] - uv[0], [0.0, -80.0], atol=1e-9)
    tilted = PinholeCamera.looking_at((0, 0, 0), 1.2, f_px=900, image_size=(960, 720), tilt_deg=15,
                                      yaw_deg=40, k1=-0.08)
    pts = np.random.default_rng(0).uniform(-0.15, 0.15, (50, 3))
    ideal = dataclasses.replace(tilted, k1=0.0).project(pts)
    np.testing.assert_allclose(tilted.undistort_pixels(tilted.project(pts)), ideal, atol=1e-8)
    np.testing.assert_allclose(tilted.project(np.zeros((1, 3))), [[479.5, 359.5]], atol=1e-9)


@pytest.mark.parametrize("tilt, dist, yaw, background, fabric, k1", [
    (0.0, 1.0, 0.0, "green", (205, 190, 165), 0.0),
    (10.0, 1.2, 35.0, "red", (60, 80, 170), -0.04),
    (20.0, 1.0, -70.0, "green", (150, 60, 40), 0.03),
])
def test_rectified_photo_matches_true_silhouette(drape, tilt, dist, yaw, background, fabric, k1):
    verts, faces, truth = drape
    cam = PinholeCamera.looking_at((0, 0, 0), dist, f_px=850 * dist, image_size=(960, 720), tilt_deg=tilt,
                                   yaw_deg=yaw, k1=k1)
    photo = render_photo(verts, faces, camera=cam, marker=MARKER, background=background, fabric_rgb=fabric,
                         noise_std=3.0, seed=1)
    sil = rectify_photo(photo, marker=MARKER, n=N, extent_m=EXTENT, camera_matrix=cam.matrix,
                        dist_coeffs=cam.dist_coeffs)
    assert sil.shape == (N, N) and sil.dtype == np.uint8 and set(np.unique(sil)) <= {0, 255}
    assert iou(sil, truth) >= 0.95
    assert abs(drape_coefficient(sil) - drape_coefficient(truth)) <= 0.02


def test_unknown_camera_is_estimated_from_marker(drape):
    """A tilted view lets the marker fix the focal length even when it is far from the prior."""
    verts, faces, truth = drape
    cam = PinholeCamera.looking_at((0, 0, 0), 1.5, f_px=1400, image_size=(960, 720), tilt_deg=20, yaw_deg=25)
    photo = render_photo(verts, faces, camera=cam, marker=MARKER, background="red", noise_std=2.0)
    k = estimate_camera_matrix(detect_marker(photo, MARKER), MARKER, photo.shape[:2])
    top = PinholeCamera.looking_at((0, 0, 0), 1.5, f_px=1400, image_size=(960, 720), yaw_deg=25)
    corners = top.project(MARKER.corners_local() + MARKER.center_m)
    corners += np.random.default_rng(0).normal(0.0, 0.03, corners.shape)
    f_prior = 26.0 / 43.27 * np.hypot(960, 720)  # phone camera, 26 mm equivalent
    # A straight top view carries no focal information: the estimate stays at the prior.
    assert abs(estimate_camera_matrix(corners, MARKER, (720, 960))[0, 0] - f_prior) < 0.05 * f_prior
    assert abs(k[0, 0] - 1400) < 0.1 * 1400
    sil = rectify_photo(photo, marker=MARKER)
    assert iou(sil, truth) >= 0.95
    assert abs(drape_coefficient(sil) - drape_coefficient(truth)) <= 0.02


def test_depth_correction_and_orientation(drape):
    """The hem below the marker plane needs the height model; a 180° camera turn is undone."""
    verts, faces, truth = drape
    truth_turned = truth[::-1, ::-1]
    assert iou(truth, truth_turned) < 0.9
    cam = PinholeCamera.looking_at((0, 0, 0), 0.9, f_px=800, image_size=(960, 720), tilt_deg=10, yaw_deg=180)
    photo = render_photo(verts, faces, camera=cam, marker=MARKER, noise_std=2.0)
    sil = rectify_photo(photo, marker=MARKER, camera_matrix=cam.matrix)
    assert iou(sil, truth) >= 0.95
    assert iou(sil, truth_turned) < 0.9
    flat = rectify_photo(photo, marker=MARKER, camera_matrix=cam.matrix, overhang_m=0.0)
    assert drape_coefficient(flat) < drape_coefficient(truth) - 0.05  # hem back-projected shrinks


def test_real_scan_photo(shared_data):
    """Photo of a real scanned drape (tilted 10°) recovers the scan's own silhouette."""
    import trimesh

    folder = sorted((shared_data / "real_cusick").iterdir())[0]
    mesh = trimesh.load(folder / "scan.ply", process=False)
    meta = json.loads((folder / "measurement.json").read_text())
    truth = cv2.imread(str(folder / meta["silhouette"]["file"]), cv2.IMREAD_GRAYSCALE)
    cam = PinholeCamera.looking_at((0, 0, 0), 1.0, f_px=900, image_size=(960, 720), tilt_deg=10, yaw_deg=120)
    photo = render_photo(np.asarray(mesh.vertices), np.asarray(mesh.faces), camera=cam, marker=MARKER,
                         background="red", noise_std=2.0)
    sil = rectify_photo(photo, marker=MARKER, camera_matrix=cam.matrix, extent_m=meta["silhouette"]["extent_m"],
                        n=truth.shape[0])
    assert iou(sil, truth) >= 0.95
    assert abs(drape_coefficient(sil) - drape_coefficient(truth)) <= 0.02


def test_errors_name_the_photo(drape, tmp_path):
    verts, faces, _ = drape
    cam = PinholeCamera.looking_at((0, 0, 0), 1.0, f_px=850, image_size=(960, 720))
    other = ArucoMarker("DICT_4X4_50", 3, 0.04, (0.0, 0.0, 0.002))
    photo = render_photo(verts, faces, camera=cam, marker=other)
    with pytest.raises(PhotoError, match=r"shot\.png: ArUco marker id 0 .*not found; detected ids: \[3\]"):
        rectify_photo(photo, marker=MARKER, source="shot.png")
    blank = np.zeros((720, 960, 3), np.uint8)
    blank[:] = (40, 150, 70)
    with pytest.raises(PhotoError, match="not found; detected ids: \\[\\]"):
        rectify_photo(blank, marker=MARKER)
    close = PinholeCamera.looking_at((0, 0, 0), 0.25, f_px=850, image_size=(960, 720))
    cropped = render_photo(verts, faces, camera=close, marker=MARKER)
    with pytest.raises(PhotoError, match="touches the photo border"):
        rectify_photo(cropped, marker=MARKER, camera_matrix=close.matrix)
    grey = render_photo(verts, faces, camera=cam, marker=MARKER)
    grey[:] = grey.mean(axis=2, keepdims=True).astype(np.uint8)
    with pytest.raises(PhotoError, match="not a saturated green or red background"):
        rectify_photo(grey, marker=MARKER, camera_matrix=cam.matrix)
    with pytest.raises(PhotoError, match="missing or not a readable image"):
        read_photo(tmp_path / "none.png")
    cv2.imwrite(str(tmp_path / "p.png"), cv2.cvtColor(photo, cv2.COLOR_RGB2BGR))
    np.testing.assert_array_equal(read_photo(tmp_path / "p.png"), photo)


def test_marker_from_dict():
    spec = {"dictionary": "DICT_4X4_50", "id": 0, "side_m": 0.04, "center_m": [0.0, 0.0, 0.002]}
    assert ArucoMarker.from_dict(spec) == MARKER
    with pytest.raises(PhotoError, match="m.json: 'dictionary' = 'DICT_9X9'"):
        ArucoMarker.from_dict({**spec, "dictionary": "DICT_9X9"}, source="m.json")
    with pytest.raises(PhotoError, match="'id' = 50 is not in DICT_4X4_50"):
        ArucoMarker.from_dict({**spec, "id": 50})
    with pytest.raises(PhotoError, match="'side_m'"):
        ArucoMarker.from_dict({**spec, "side_m": 40})
    with pytest.raises(PhotoError, match=r"missing field\(s\) \['center_m'\]"):
        ArucoMarker.from_dict({k: v for k, v in spec.items() if k != "center_m"})
