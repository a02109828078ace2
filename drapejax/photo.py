"""Top-view photos of a Cusick drape: a synthetic renderer and the photo → silhouette rectifier.

A drape photo (spec ``photo`` entry) is an RGB picture taken from above by a perspective
camera, fabric on a green or red background, with an ArUco marker lying flat on the top
clamp, its edges along warp (+x) and weft (+y). Seed 001 (§6.2.2) rectifies such photos
into the 256 × 256 orthographic silhouette with the marker; this module does the same.

Why not just a plane homography: the marker fixes the plane z = z_marker, but the outline
of a drape is formed by the hem, which hangs 2–6 cm below it. Back-projected onto the
marker plane it shrinks towards the camera's foot point by the factor h / (h + drop) and,
in a tilted view, shifts by drop · tan(tilt) (1.8 cm at 20°): the drape coefficient comes
out about 0.1 too low at 1 m. ``rectify_photo`` therefore recovers the camera pose from the
marker and maps each silhouette pixel through a height model of the outline: the
outermost fabric at radius r hangs ``sqrt(L² − (r − R_disk)²)`` below the disc (the hem at
chord length L, the overhang, from the disc edge). On the 48 real scans in
``shared/data/real_cusick`` the outermost vertex per azimuth follows this with an rms
error of 5 mm, and photos rendered from those scans (0.6–1 m, 0–20° tilt, known intrinsics)
rectify to their silhouettes with a drape-coefficient error of −0.008 on average, 0.02 at
the 90th percentile.

Limits: the photo cannot show a hem hidden behind the disc edge, which happens on the far
side of a tilted view when the skirt is steeper than the viewing ray (limp fabric, tilt
above ~10°); there the widest hem consistent with the outline is taken, biasing the drape
coefficient up by up to ~0.02 at 20° tilt. Without intrinsics the focal length comes from
the marker only in clearly tilted views (``estimate_camera_matrix``); in a straight top
view it is a prior, and a focal length 2× off shifts the drape coefficient by ~0.05.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Float, Int, UInt8

from .mesh import CUSICK_RADIUS_M, DISK_RADIUS_M

BACKGROUND_RGB = {"green": (40, 150, 70), "red": (180, 30, 35)}
"""Nominal background colours of the synthetic photos (RGB)."""

_BACKGROUND_HUE = {"green": 60.0, "red": 0.0}  # OpenCV hue units (degrees / 2)
_HUE_TOLERANCE = 18.0  # OpenCV hue units around the background hue
_CLAMP_RGB = (150, 150, 150)
_LIGHT_DIR = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
_SUPERSAMPLE = 3
_MODULE_PX = 16
_DIAGONAL_35MM = 43.27  # mm, diagonal of the 36 × 24 mm frame

DEFAULT_FOCAL_35MM = 26.0
"""Prior focal length (35 mm equivalent, mm) of a phone main camera, used when the photo's
camera matrix is unknown and the marker view is too straight to measure it."""


class PhotoError(ValueError):
    """A drape photo that cannot be rectified; the message names the photo and the reason."""


@dataclasses.dataclass(frozen=True)
class ArucoMarker:
    """The ArUco marker lying on the top clamp (spec ``photo.marker``).

    Attributes:
        dictionary: OpenCV predefined dictionary name, e.g. ``"DICT_4X4_50"``.
        id: marker id in that dictionary.
        side_m: side of the black square (outer edge of the black border), m.
        center_m: (3,) world position of the marker centre, m (z just above the disc top).
    """

    dictionary: str
    id: int
    side_m: float
    center_m: tuple[float, float, float]

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "photo.marker") -> "ArucoMarker":
        """Parse the spec's ``photo.marker`` JSON object; errors name ``source`` and the field."""
        if not isinstance(d, dict):
            raise PhotoError(f"{source}: expected an object with dictionary, id, side_m, center_m")
        missing = [k for k in ("dictionary", "id", "side_m", "center_m") if k not in d]
        if missing:
            raise PhotoError(f"{source}: missing field(s) {missing}")
        if not isinstance(d["dictionary"], str) or not hasattr(cv2.aruco, d["dictionary"]):
            raise PhotoError(f"{source}: 'dictionary' = {d['dictionary']!r} is not an OpenCV ArUco dictionary")
        if isinstance(d["id"], bool) or not isinstance(d["id"], int) or d["id"] < 0:
            raise PhotoError(f"{source}: 'id' must be a non-negative integer, got {d['id']!r}")
        side = d["side_m"]
        if isinstance(side, bool) or not isinstance(side, (int, float)) or not 0.0 < side < 1.0:
            raise PhotoError(f"{source}: 'side_m' must be a side length in metres in (0, 1), got {side!r}")
        c = d["center_m"]
        if (not isinstance(c, (list, tuple)) or len(c) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in c)):
            raise PhotoError(f"{source}: 'center_m' must be [x, y, z] in metres, got {c!r}")
        marker = cls(d["dictionary"], d["id"], float(side), tuple(float(v) for v in c))
        if marker.id >= marker.aruco_dictionary().bytesList.shape[0]:
            raise PhotoError(f"{source}: 'id' = {marker.id} is not in {marker.dictionary}")
        return marker

    def aruco_dictionary(self) -> cv2.aruco.Dictionary:
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def corners_local(self, side_m: float | None = None) -> Float[np.ndarray, "4 3"]:
        """Corners relative to the centre, m, in ArUco order (image top-left, top-right,
        bottom-right, bottom-left of the marker = (−x, +y), (+x, +y), (+x, −y), (−x, −y))."""
        h = 0.5 * (self.side_m if side_m is None else side_m)
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def _rx(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera with one radial distortion coefficient (OpenCV conventions).

    Orientation: start looking straight down (−z) with image right = +x and image up = +y,
    then turn by ``yaw_deg`` about the world z axis, tilt by ``pitch_deg`` about the
    camera's x axis (positive tilts the view towards image up) and roll by ``roll_deg``
    about the optical axis. Pixel centres are at integer coordinates.

    Attributes:
        f_px: focal length, pixels (square pixels).
        cx, cy: principal point, pixels.
        position_m: (3,) optical centre in the world frame, m.
        yaw_deg, pitch_deg, roll_deg: orientation, degrees.
        k1: radial distortion, x_d = x (1 + k1 r²) in normalised coordinates.
    """

    f_px: float
    cx: float
    cy: float
    position_m: tuple[float, float, float]
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    k1: float = 0.0

    @classmethod
    def looking_at(cls, target_m, distance_m: float, *, f_px: float, image_size: tuple[int, int],
                   tilt_deg: float = 0.0, yaw_deg: float = 0.0, roll_deg: float = 0.0,
                   k1: float = 0.0) -> "PinholeCamera":
        """Camera at ``distance_m`` from ``target_m`` (3,), its optical axis through the target
        and tilted ``tilt_deg`` from the vertical; principal point at the image centre.
        ``image_size`` is (width, height) in pixels."""
        axis = _rz(yaw_deg) @ np.array([0.0, np.sin(np.deg2rad(tilt_deg)), -np.cos(np.deg2rad(tilt_deg))])
        pos = np.asarray(target_m, float) - distance_m * axis
        w, h = image_size
        return cls(float(f_px), (w - 1) / 2.0, (h - 1) / 2.0, tuple(float(v) for v in pos),
                   float(yaw_deg), float(tilt_deg), float(roll_deg), float(k1))

    @property
    def rotation(self) -> Float[np.ndarray, "3 3"]:
        """World → camera rotation (camera x right, y down, z forward)."""
        cam_to_world = _rz(self.yaw_deg) @ np.diag([1.0, -1.0, -1.0]) @ _rx(self.pitch_deg) @ _rz(self.roll_deg)
        return cam_to_world.T

    @property
    def matrix(self) -> Float[np.ndarray, "3 3"]:
        """Intrinsic matrix K."""
        return np.array([[self.f_px, 0.0, self.cx], [0.0, self.f_px, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> Float[np.ndarray, "5"]:
        """OpenCV distortion vector (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, 0.0, 0.0, 0.0, 0.0])

    def to_camera(self, points: Float[np.ndarray, "k 3"]) -> Float[np.ndarray, "k 3"]:
        """World points (m) in camera coordinates (m); column 2 is the depth."""
        return (np.asarray(points, float) - np.asarray(self.position_m)) @ self.rotation.T

    def project(self, points: Float[np.ndarray, "k 3"]) -> Float[np.ndarray, "k 2"]:
        """Pixel coordinates (column, row) of world points (m) in front of the camera."""
        pc = self.to_camera(points)
        xn = pc[:, :2] / pc[:, 2:3]
        xd = xn * (1.0 + self.k1 * np.sum(xn * xn, axis=1, keepdims=True))
        return self.f_px * xd + np.array([self.cx, self.cy])

    def undistort_pixels(self, uv: Float[np.ndarray, "k 2"]) -> Float[np.ndarray, "k 2"]:
        """Ideal (distortion-free) pixel coordinates of observed pixels (inverse of ``k1``)."""
        c = np.array([self.cx, self.cy])
        xd = (np.asarray(uv, float) - c) / self.f_px
        rd = np.linalg.norm(xd, axis=1)
        ru = rd.copy()
        for _ in range(20):  # Newton on ru (1 + k1 ru²) = rd
            step = (ru * (1.0 + self.k1 * ru**2) - rd) / (1.0 + 3.0 * self.k1 * ru**2)
            ru = ru - step
            if not np.max(np.abs(step)) > 1e-13:
                break
        if not np.all(np.isfinite(ru)) or np.any(np.abs(ru * (1.0 + self.k1 * ru**2) - rd) > 1e-9):
            raise ValueError(f"PinholeCamera: k1 = {self.k1} is too strong to invert over this image")
        scale = np.where(rd > 0, ru / np.maximum(rd, 1e-300), 1.0)
        return xd * scale[:, None] * self.f_px + c


def render_photo(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], *,
                 camera: PinholeCamera, marker: ArucoMarker, background: str = "green",
                 fabric_rgb: tuple[int, int, int] = (205, 190, 165),
                 image_size: tuple[int, int] = (960, 720), disk_radius_m: float = DISK_RADIUS_M,
                 noise_std: float = 0.0, seed: int = 0) -> UInt8[np.ndarray, "h w 3"]:
    """Synthetic drape photo: fabric mesh, grey top clamp and ArUco marker on a coloured ground.

    The fabric is shaded by |normal · light| so folds show, drawn far-to-near (painter's
    order); the clamp (radius ``disk_radius_m`` at the marker's height) and the marker with
    a one-module white quiet zone lie on top. The image is rendered 3× supersampled and
    area-averaged, then radially distorted by ``camera.k1``.

    Args:
        verts: (n, 3) draped vertex positions, m, world frame.
        faces: (m, 3) triangle vertex indices.
        camera: the camera.
        marker: the ArUco marker (its centre z is the clamp top).
        background: ``"green"`` or ``"red"``.
        fabric_rgb: unshaded fabric colour.
        image_size: (width, height), pixels.
        disk_radius_m: radius of the top clamp, m.
        noise_std: standard deviation of additive Gaussian pixel noise (0–255 scale).
        seed: noise seed.

    Returns:
        (height, width, 3) uint8 RGB image.
    """
    if background not in BACKGROUND_RGB:
        raise ValueError(f"render_photo: background must be one of {sorted(BACKGROUND_RGB)}, got {background!r}")
    w, h = image_size
    s = _SUPERSAMPLE
    ideal_cam = dataclasses.replace(camera, k1=0.0)
    # Ideal (undistorted) coordinates of every output pixel, and a canvas that covers them.
    cols, rows = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    out_px = np.stack([cols.ravel(), rows.ravel()], 1)
    ideal_px = camera.undistort_pixels(out_px) if camera.k1 != 0.0 else out_px
    lo = np.floor(np.minimum(ideal_px.min(0), 0.0)) - 2.0
    hi = np.ceil(np.maximum(ideal_px.max(0), [w - 1, h - 1])) + 2.0
    wc, hc = (hi - lo + 1).astype(int)

    def to_canvas(points):
        return (ideal_cam.project(points) - lo + 0.5) * s - 0.5

    canvas = np.empty((hc * s, wc * s, 3), np.uint8)
    canvas[:] = BACKGROUND_RGB[background]
    _draw_fabric(canvas, np.asarray(verts, float), np.asarray(faces), ideal_cam, to_canvas, fabric_rgb)
    zc = marker.center_m[2]
    t = np.linspace(0.0, 2 * np.pi, 361)[:-1]
    clamp = np.stack([disk_radius_m * np.cos(t), disk_radius_m * np.sin(t), np.full_like(t, zc)], 1)
    cv2.fillPoly(canvas, [np.round(to_canvas(clamp) * 16).astype(np.int32)], _CLAMP_RGB, cv2.LINE_8, 4)
    _draw_marker(canvas, marker, to_canvas)
    img = cv2.resize(canvas, (wc, hc), interpolation=cv2.INTER_AREA)
    maps = (ideal_px - lo).astype(np.float32)
    img = cv2.remap(img, maps[:, 0].reshape(h, w), maps[:, 1].reshape(h, w), cv2.INTER_LINEAR)
    if noise_std > 0:
        noise = np.random.default_rng(seed).normal(0.0, noise_std, img.shape)
        img = np.clip(np.round(img + noise), 0, 255).astype(np.uint8)
    return img


def _draw_fabric(canvas, verts, faces, cam, to_canvas, rgb):
    """Flat-shaded triangles, farthest first."""
    p = verts[faces]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    shade = 0.35 + 0.65 * np.abs(nrm @ _LIGHT_DIR)
    colors = np.clip(np.outer(shade, rgb), 0, 255).astype(int)
    depth = cam.to_camera(verts)[:, 2][faces].mean(1)
    tri = np.round(to_canvas(verts) * 16).astype(np.int32)[faces]
    for f in np.argsort(-depth):
        cv2.fillConvexPoly(canvas, tri[f], colors[f].tolist(), cv2.LINE_8, 4)


def _draw_marker(canvas, marker: ArucoMarker, to_canvas):
    """Warp the marker with a white one-module quiet zone onto its 3D pose."""
    bits = marker.aruco_dictionary().markerSize
    img = cv2.aruco.generateImageMarker(marker.aruco_dictionary(), marker.id, (bits + 2) * _MODULE_PX, borderBits=1)
    img = cv2.copyMakeBorder(img, *(4 * [_MODULE_PX]), cv2.BORDER_CONSTANT, value=255)
    size = img.shape[0]
    src = np.array([[-0.5, -0.5], [size - 0.5, -0.5], [size - 0.5, size - 0.5], [-0.5, size - 0.5]], np.float32)
    quiet_side = marker.side_m * (bits + 4) / (bits + 2)
    dst = to_canvas(marker.corners_local(quiet_side) + np.asarray(marker.center_m)).astype(np.float32)
    x0, y0 = np.maximum(np.floor(dst.min(0)).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.ceil(dst.max(0)).astype(int) + 2, [canvas.shape[1], canvas.shape[0]])
    hom = cv2.getPerspectiveTransform(src, dst - np.array([x0, y0], np.float32))
    dsize = (int(x1 - x0), int(y1 - y0))
    warped = cv2.warpPerspective(img, hom, dsize, flags=cv2.INTER_LINEAR)[..., None]
    alpha = cv2.warpPerspective(np.full_like(img, 255), hom, dsize, flags=cv2.INTER_LINEAR)
    a = (alpha.astype(np.float32) / 255.0)[..., None]
    patch = canvas[y0:y1, x0:x1]
    patch[:] = np.round(a * warped + (1.0 - a) * patch).astype(np.uint8)


def read_photo(path: str | Path) -> UInt8[np.ndarray, "h w 3"]:
    """Read a photo file as RGB uint8; a missing or unreadable file raises PhotoError."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise PhotoError(f"{path}: photo file is missing or not a readable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def rectify_photo(photo_rgb: UInt8[np.ndarray, "h w 3"], *, marker: ArucoMarker, n: int = 256,
                  extent_m: float = 0.16, background: str = "auto",
                  camera_matrix: Float[np.ndarray, "3 3"] | None = None,
                  dist_coeffs: Float[np.ndarray, " k"] | None = None,
                  disk_radius_m: float = DISK_RADIUS_M,
                  overhang_m: float = CUSICK_RADIUS_M - DISK_RADIUS_M,
                  source: str = "photo") -> UInt8[np.ndarray, "n n"]:
    """Orthographic top-view silhouette (spec grid) of a drape photo.

    Steps: detect the marker; recover the camera pose from its corners (``camera_matrix``
    and ``dist_coeffs`` when known, else a focal length estimated from the marker, see
    ``estimate_camera_matrix``); segment fabric (everything that is not the green/red
    background: disc, clamp and marker count as covered) in HSV, open/close, keep the
    largest component and fill its holes; then for every silhouette pixel project the
    outline height model (module docstring) through the camera, distortion included, and
    sample the mask. Mapping the grid through the lens model replaces a separate
    undistortion pass (one resampling instead of two).

    Args:
        photo_rgb: (h, w, 3) uint8 RGB photo.
        marker: the ArUco marker on the clamp.
        n: silhouette size, pixels.
        extent_m: half width of the silhouette window, m.
        background: ``"green"``, ``"red"`` or ``"auto"`` (from the photo border).
        camera_matrix: (3, 3) intrinsics K, pixels; ``None`` estimates it.
        dist_coeffs: OpenCV distortion coefficients (k1, k2, p1, p2[, k3]); ``None`` = none.
        disk_radius_m: support-disc radius, m.
        overhang_m: specimen radius minus disc radius, m; 0 rectifies on the plane z = 0.
        source: name of the photo for error messages (its file path).

    Returns:
        (n, n) uint8 silhouette, 255 = fabric; row 0 is +y, columns grow with +x.
    """
    photo = np.asarray(photo_rgb)
    if photo.ndim != 3 or photo.shape[2] != 3 or photo.dtype != np.uint8:
        raise PhotoError(f"{source}: expected an RGB uint8 image, got shape {photo.shape} dtype {photo.dtype}")
    if background not in ("auto", *BACKGROUND_RGB):
        raise PhotoError(f"{source}: background must be 'auto', 'green' or 'red', got {background!r}")
    corners = detect_marker(photo, marker, source=source)
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, float)
    if camera_matrix is None:
        camera_matrix = estimate_camera_matrix(corners, marker, photo.shape[:2])
    k = np.asarray(camera_matrix, float)
    rvec, tvec = marker_pose(corners, marker, k, dist)
    mask = fabric_mask(photo, background, source=source)
    half = extent_m * (1.0 - 1.0 / n)
    xs = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(xs, xs[::-1])
    z = outline_height(np.hypot(gx, gy), disk_radius_m, overhang_m)
    world = np.stack([gx.ravel(), gy.ravel(), z.ravel()], 1) - np.asarray(marker.center_m)
    uv, _ = cv2.projectPoints(world, rvec, tvec, k, dist)
    uv = uv.reshape(n, n, 2).astype(np.float32)
    sil = cv2.remap(mask.astype(np.float32), uv[..., 0], uv[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return np.where(sil >= 0.5, 255, 0).astype(np.uint8)


def photo_silhouette(m, *, n: int = 256, extent_m: float = 0.16) -> UInt8[np.ndarray, "n n"]:
    """Top-view silhouette of a measurement's photo on the spec grid: ``rectify_photo`` with the
    folder's marker, support disc and overhang (specimen radius or half side minus disc radius).

    ``m`` is a ``drapejax.io.Measurement`` with ``photo`` and ``photo_marker``; the estimators use
    this when a folder has a photo but no silhouette, height map or scan mesh.
    """
    if m.photo is None or m.photo_marker is None:
        raise PhotoError(f"{m.path or 'measurement'}: no photo with a marker to rectify")
    entry = m.extra.get("photo") if isinstance(m.extra, dict) else None
    name = entry.get("file", "photo") if isinstance(entry, dict) else "photo"
    source = str(Path(m.path) / name) if m.path is not None else name
    return rectify_photo(m.photo, marker=ArucoMarker.from_dict(m.photo_marker), n=n, extent_m=extent_m,
                         disk_radius_m=m.disk_radius_m, overhang_m=m.specimen_radius_m - m.disk_radius_m,
                         source=source)


def outline_height(r_m, disk_radius_m: float = DISK_RADIUS_M,
                   overhang_m: float = CUSICK_RADIUS_M - DISK_RADIUS_M):
    """Height model z(r) (m) of the outermost fabric at radius ``r_m`` (m): 0 on the disc,
    ``−sqrt(L² − (r − R)²)`` beyond it (the hem at chord length L from the disc edge), 0
    beyond R + L."""
    reach = np.asarray(r_m, float) - disk_radius_m
    drop = np.sqrt(np.maximum(overhang_m**2 - reach**2, 0.0))
    return np.where(reach > 0.0, -drop, 0.0)


def detect_marker(photo_rgb: UInt8[np.ndarray, "h w 3"], marker: ArucoMarker, *,
                  source: str = "photo") -> Float[np.ndarray, "4 2"]:
    """Sub-pixel image corners (pixels, ArUco order) of the marker; PhotoError if absent."""
    gray = cv2.cvtColor(np.asarray(photo_rgb), cv2.COLOR_RGB2GRAY)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(marker.aruco_dictionary(), params)
    corners, ids, _ = detector.detectMarkers(gray)
    found = [] if ids is None else [int(i) for i in ids.ravel()]
    hits = [c for c, i in zip(corners, found) if i == marker.id]
    if len(hits) != 1:
        what = "not found" if not hits else f"found {len(hits)} times"
        raise PhotoError(f"{source}: ArUco marker id {marker.id} ({marker.dictionary}) {what}; "
                         f"detected ids: {sorted(found)}")
    return _refine_corners(gray, hits[0].reshape(4, 2).astype(float), marker)


def _refine_corners(gray, corners, marker: ArucoMarker):
    """Align the known marker pattern to the photo (ECC, homography model) for corners about
    ten times more precise than corner sub-pixel refinement (0.02 px vs 0.2 px in synthetic
    photos), which the tilt of the pose needs. Keeps the detected corners if ECC fails."""
    bits = marker.aruco_dictionary().markerSize
    side_px = np.mean(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1))
    m = max(4, int(np.ceil(side_px / (bits + 2))))  # template pixels per module ≈ photo scale
    size = (bits + 2) * m
    tpl = cv2.aruco.generateImageMarker(marker.aruco_dictionary(), marker.id, size, borderBits=1)
    pad = m // 2  # half a module of the white quiet zone; beyond it lies the clamp
    tpl = cv2.copyMakeBorder(tpl, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255).astype(np.float32)
    a, b = pad - 0.5, pad + size - 0.5
    tc = np.array([[a, a], [b, a], [b, b], [a, b]], np.float32)
    warp = cv2.getPerspectiveTransform(tc, corners.astype(np.float32)).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    try:
        _, warp = cv2.findTransformECC(tpl, gray.astype(np.float32), warp, cv2.MOTION_HOMOGRAPHY, crit, None, 1)
    except cv2.error:
        return corners
    refined = cv2.perspectiveTransform(tc[None], warp)[0].astype(float)
    return refined if np.max(np.abs(refined - corners)) < 1.0 else corners


def marker_pose(corners: Float[np.ndarray, "4 2"], marker: ArucoMarker, camera_matrix, dist_coeffs):
    """Marker-frame → camera pose (rvec, tvec) from its four image corners (IPPE, then LM)."""
    obj = marker.corners_local()
    _, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, corners, camera_matrix, dist_coeffs,
                                                flags=cv2.SOLVEPNP_IPPE_SQUARE)
    best = int(np.argmin(np.ravel(errs)))
    return cv2.solvePnPRefineLM(obj, corners, camera_matrix, dist_coeffs, rvecs[best].copy(), tvecs[best].copy())


def estimate_camera_matrix(corners: Float[np.ndarray, "4 2"], marker: ArucoMarker,
                           image_hw: tuple[int, int], *, corner_std_px: float = 0.03,
                           prior_focal_35mm: float = DEFAULT_FOCAL_35MM,
                           prior_log_std: float = 0.25) -> Float[np.ndarray, "3 3"]:
    """Intrinsics K from the marker, assuming square pixels and a centred principal point.

    The marker homography gives two linear constraints on 1/f² (orthogonal, equal-norm
    rotation columns; Zhang 2000). They carry information only in proportion to the
    perspective foreshortening of the marker, i.e. to the camera tilt: none in a straight
    top view, about ±10% at 10–20° with a 4 cm marker at 1–1.5 m. The estimate is therefore combined, by inverse
    variance in 1/f², with a prior focal length (a phone camera's 26 mm equivalent, log
    standard deviation ``prior_log_std``); its own variance comes from re-estimating with
    ``corner_std_px`` of noise added to the corners.

    Args:
        corners: (4, 2) marker corners in the photo, pixels (ArUco order).
        marker: the marker.
        image_hw: (height, width) of the photo, pixels.
        corner_std_px: assumed standard deviation of the corner positions, pixels.
        prior_focal_35mm: prior focal length as a 35 mm-equivalent, mm.
        prior_log_std: standard deviation of log(focal length) in the prior.
    """
    h_img, w_img = image_hw
    c = np.array([(w_img - 1) / 2.0, (h_img - 1) / 2.0])
    plane = marker.corners_local()[:, :2].astype(np.float32)

    def solve(pts):
        """(1/f², viewing angle of the marker in rad under the prior focal length)."""
        hom = cv2.getPerspectiveTransform(plane, (pts.reshape(4, 2) - c).astype(np.float32))
        h1, h2 = hom[:, 0], hom[:, 1]
        # a / f² + b = 0 for each constraint on the first two rotation columns.
        a = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2])
        b = np.array([h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2])
        m = np.diag([1.0 / f0, 1.0 / f0, 1.0]) @ hom
        normal = np.cross(m[:, 0], m[:, 1])
        cos_view = abs(normal @ m[:, 2]) / (np.linalg.norm(normal) * np.linalg.norm(m[:, 2]))
        return (-(a @ b) / (a @ a) if a @ a > 0 else np.inf), np.arccos(min(cos_view, 1.0))

    f0 = prior_focal_35mm / _DIAGONAL_35MM * np.hypot(w_img, h_img)
    x0 = f0**-2.0
    var0 = (2.0 * prior_log_std * x0) ** 2  # log-normal prior, linearised in 1/f²
    x, view = solve(corners.ravel())
    # Spread under corner noise by Monte Carlo. Near a straight view 1/f² is a ratio of
    # noise-sized terms and the observed view angle is mostly noise: use the prior alone
    # unless the view angle stands out (3 sigma) from its own noise.
    jitter = np.random.default_rng(0).normal(0.0, corner_std_px, (64, 8))
    xs, views = np.array([solve(corners.ravel() + j) for j in jitter]).T
    var = (1.4826 * np.median(np.abs(xs - np.median(xs)))) ** 2
    informative = view > 3.0 * np.std(views) and np.isfinite(x) and np.isfinite(var)
    post = (x * var0 + x0 * var) / (var + var0) if informative else x0
    # A noisy estimate can push 1/f² towards zero or below: cap f at three prior sigmas.
    f = 1.0 / np.sqrt(max(post, x0 * np.exp(-6.0 * prior_log_std)))
    return np.array([[f, 0.0, c[0]], [0.0, f, c[1]], [0.0, 0.0, 1.0]])


def fabric_mask(photo_rgb: UInt8[np.ndarray, "h w 3"], background: str = "auto", *,
                source: str = "photo") -> UInt8[np.ndarray, "h w"]:
    """Covered area (1) vs background (0): the largest non-background component, holes filled."""
    hsv = cv2.cvtColor(np.asarray(photo_rgb), cv2.COLOR_RGB2HSV).astype(float)
    hue, sat, val = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    hh, ww = hue.shape
    rim = np.zeros((hh, ww), bool)
    b = max(2, min(hh, ww) // 40)
    rim[:b], rim[-b:], rim[:, :b], rim[:, -b:] = True, True, True, True
    if background == "auto":
        ang = np.deg2rad(2.0 * hue[rim & (sat > 90)])
        if ang.size < 0.5 * rim.sum():
            raise PhotoError(f"{source}: the photo border is not a saturated green or red background")
        mean_hue = np.rad2deg(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean())) / 2.0 % 180.0
        dist = {k: min(abs(mean_hue - v), 180.0 - abs(mean_hue - v)) for k, v in _BACKGROUND_HUE.items()}
        background = min(dist, key=dist.get)
        if dist[background] > _HUE_TOLERANCE:
            raise PhotoError(f"{source}: background hue {2 * mean_hue:.0f}° is neither green nor red")
    dh = np.abs(hue - _BACKGROUND_HUE[background])
    near_hue = np.minimum(dh, 180.0 - dh) <= _HUE_TOLERANCE
    ref = rim & near_hue & (sat > 60)
    if ref.sum() < 0.5 * rim.sum():
        raise PhotoError(f"{source}: the photo border is not mostly {background} background")
    bg = near_hue & (sat > 0.5 * np.median(sat[ref])) & (val > 0.3 * np.median(val[ref]))
    k = max(3, (min(hh, ww) // 240) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    fg = cv2.morphologyEx((~bg).astype(np.uint8), cv2.MORPH_OPEN, kernel)
    fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, kernel)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if count < 2:
        raise PhotoError(f"{source}: no fabric found on the {background} background")
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, bw, bh = stats[big, :4]
    if x == 0 or y == 0 or x + bw == ww or y + bh == hh:
        raise PhotoError(f"{source}: the fabric touches the photo border; the whole drape must be in view")
    contours, _ = cv2.findContours((labels == big).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    out = np.zeros((hh, ww), np.uint8)
    cv2.drawContours(out, contours, -1, 1, thickness=cv2.FILLED)
    return out


__all__ = ["PhotoError", "ArucoMarker", "PinholeCamera", "BACKGROUND_RGB", "render_photo", "read_photo",
           "rectify_photo", "photo_silhouette", "outline_height", "detect_marker", "marker_pose",
           "estimate_camera_matrix", "fabric_mask"]
