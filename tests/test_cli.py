"""The command line: simulate writes a spec-conformant measurement folder that round-trips."""

import json
import subprocess
import sys

import numpy as np
import pytest

from drapejax.io import load_measurement, load_truth
from drapejax.observe import silhouette


def test_simulate_writes_measurement_folder_that_round_trips(tmp_path):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"density": 0.2, "bend_k1_warp": 1.4e-5, "bend_k1_weft": 9e-6,
                                  "bend_k1_bias": 1.1e-5, "bend_k2_warp": -3e-8}))
    out = tmp_path / "m"
    r = subprocess.run([sys.executable, "-m", "drapejax.cli", "simulate", "--params", str(params), "--test", "cusick",
                        "--spacing-mm", "30", "--rim-mm", "10", "--seed", "0", "--quick", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    info = json.loads(r.stdout)
    assert info["status"] == "at_rest"
    assert sorted(p.name for p in out.iterdir()) == ["height.npy", "measurement.json", "scan.ply", "silhouette.png",
                                                      "truth.json"]
    m = load_measurement(out)
    assert m.test == "cusick" and m.areal_density_kg_m2 == 0.2 and m.warp_angle_deg == 0.0
    truth = load_truth(out)
    assert truth["params"]["bend_k2_warp"] == -3e-8
    assert truth["mesh"]["rim_spacing_m"] == 0.01 and truth["mesh"]["verts"] == info["verts"]
    assert truth["mesh"]["buckling"] is False
    # Render again from the stored scan: the stored silhouette is reproduced to within a pixel.
    again = silhouette(m.scan_vertices, m.scan_faces, n=m.silhouette.shape[0], extent_m=m.silhouette_extent_m)
    assert np.mean(again != m.silhouette) < 1e-3
    # The drape hangs: hem below the disc top, nothing above the clamp.
    assert np.nanmin(m.height) < -0.02 and np.nanmax(m.height) < 0.005


def test_bad_parameter_file_is_one_clear_error(tmp_path):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"density": 0.2, "bend_k1_warp": 13.8, "bend_k1_weft": 9e-6, "bend_k1_bias": 1e-5}))
    r = subprocess.run([sys.executable, "-m", "drapejax.cli", "simulate", "--params", str(params), "--out",
                        str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "bend_k1_warp" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_fit_mesh_defaults_of_the_commands_are_the_library_defaults():
    """`estimate` and `diagnose` default to the mesh ``refine.fit`` defaults to (the fitted k1 depend on it)."""
    from drapejax import refine
    from drapejax.cli import build_parser

    ap = build_parser()
    for cmd in (["estimate", "d"], ["diagnose", "d"]):
        a = ap.parse_args(cmd)
        assert a.spacing_mm / 1000.0 == refine.FIT_SPACING_M and a.rim_mm / 1000.0 == refine.FIT_RIM_SPACING_M


@pytest.mark.experiment
def test_bench_prints_the_fields_the_simulator_issue_names():
    """`drapejax bench --json` carries the benchmark's schema; a coarse, tiny run with the device's
    default batch strategy only, so no timing is judged. (30 mm: on the 40 mm mesh the
    0.8x-density member creeps to rest in 192 of its 200 steps, and rounding in the linear
    solver decides whether it gets there.) Without the Newton peer (its Style3D run on this mesh took
    386 s on two CPU cores) and without the two whole `simulate` processes (about a minute each)."""
    r = subprocess.run([sys.executable, "-m", "drapejax.cli", "bench", "--spacing-mm", "30", "--repeats", "1",
                        "--batch", "2", "--strategies=", "--no-newton", "--no-process", "--json"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    for key in ("verts", "rest_s", "compile_s", "grad_s", "batch16_per_min", "peak_mb", "newton_rest_s",
                "speedup_vs_newton", "multilevel_rest_s", "multilevel_grad_s", "multilevel_levels",
                "simulate_process_s"):
        assert key in out, key
    assert out["multilevel_status"] == [0] and [lv["spacing_mm"] for lv in out["multilevel_levels"]] == [30.0]
    assert out["simulate_process_s"] is None  # --no-process; `simulate` itself is tested on its own
    assert out["status"] == [0] and out["batch_status"] == [0, 0]
    assert out["batch16_per_min"] is None and out["batch_per_min"] > 0  # a batch of 2 is not the issue's 16
    assert list(out["batch_per_min_by_strategy"]) == [out["batch_strategy"]]
    assert out["newton_rest_s"] is None and out["speedup_vs_newton"] is None
    assert out["multilevel_newton_rest_s"] is None and out["multilevel_speedup_vs_newton"] is None


def test_validate_exits_nonzero_when_a_case_misses_the_tolerance(capsys, shared_data):
    """`drapejax validate cantilever` exits 0 when every case is within its tolerance of the master
    curve (Γ = 0.1 on 5 mm) and 1 when one is not (Γ = 100 on 10 mm: its 21 mm bending zone spans two spacings;
    42 % too far), so scripts can rely on it; a malformed grid is an error (2)."""
    from drapejax.cli import main
    from drapejax.validate import TOLERANCE

    assert main(["validate", "cantilever", "--gammas", "0.1", "--angles", "0", "--spacings-mm", "5", "--json"]) == 0
    ok = json.loads(capsys.readouterr().out)
    assert ok["passed"] and ok["tolerance"] == TOLERANCE and len(ok["cases"]) == 1 and ok["max_rel_err"] < TOLERANCE
    assert main(["validate", "cantilever", "--gammas", "100", "--angles", "30", "--spacings-mm", "10", "--json"]) == 1
    bad = json.loads(capsys.readouterr().out)
    assert not bad["passed"] and bad["max_rel_err"] > TOLERANCE
    assert main(["validate", "cantilever", "--spacings-mm", "5,x"]) == 2
    assert "--spacings-mm" in capsys.readouterr().err


def test_a_first_estimate_loads_neither_the_solver_nor_unneeded_libraries():
    """What ``drapejax estimate DIR --no-refine`` imports to read a folder and run the packaged model
    leaves out the solver and the libraries that only other commands need (each costs start-up time:
    docs/results/2026-12-06-start-up.md); the strip-tensile reader it calls is inside ``drapejax.refine``,
    whose names load on first use."""
    heavy = ("drapejax.solve", "drapejax.inverse.dataset", "trimesh", "scipy.signal", "scipy.spatial", "optax",
             "optimistix")
    code = ("import sys; import drapejax.cli, drapejax.io, drapejax.inverse.estimate, drapejax.refine.tensile; "
            f"print([m for m in {heavy!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
