"""Test configuration: float64 everywhere, strict rank promotion, shared data location."""

import os
import tempfile
from pathlib import Path

# pytest-xdist workers share one GPU: without this each would try to preallocate 75 % of its memory.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import jax  # noqa: E402
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

# Tests that trace the same drape program (a fixture's mesh built again, another worker) load it
# from JAX's persistent cache instead of compiling it again; DRAPEJAX_TEST_CACHE_DIR="" turns it off.
_cache = os.environ.get("DRAPEJAX_TEST_CACHE_DIR", os.path.join(tempfile.gettempdir(), "drapejax-test-jax-cache"))
if _cache:
    from drapejax import compile_cache  # noqa: E402

    compile_cache.enable(_cache)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
DATA = SHARED / "data"


@pytest.fixture
def key():
    return jax.random.PRNGKey(0)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"shared data not found at {DATA}")
    return DATA


@pytest.fixture
def single_observation(shared_data, tmp_path):
    """A real capture (f01) and two folders made from its scan that each hold one observation:
    the scan as a point cloud (no faces), and a photo of it (tilted 8°, ArUco marker on the clamp).
    Returns (the capture, the point-cloud folder, the photo folder)."""
    import numpy as np

    from drapejax.io import load_measurement, write_measurement
    from drapejax.photo import ArucoMarker, PinholeCamera, render_photo

    m = load_measurement(sorted((shared_data / "real_cusick").iterdir())[0])
    v, f = np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces)
    marker = {"dictionary": "DICT_4X4_50", "id": 0, "side_m": 0.04, "center_m": [0.0, 0.0, 0.002]}
    cam = PinholeCamera.looking_at((0, 0, 0), 1.0, f_px=900, image_size=(960, 720), tilt_deg=8, yaw_deg=30)
    photo = render_photo(v, f, camera=cam, marker=ArucoMarker.from_dict(marker), background="green", noise_std=2.0)
    common = dict(test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09, areal_density_kg_m2=None,
                  warp_angle_deg=None)
    return (m, write_measurement(tmp_path / "cloud", scan=(v, None), **common),
            write_measurement(tmp_path / "photo", photo=photo, photo_marker=marker, **common))
