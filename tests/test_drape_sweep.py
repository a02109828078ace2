"""The Hydra drape sweep (``experiments/drape_sweep.py``): a multirun over two fabrics writes one
measurement folder and one JSON line per run, and the softer fabric drapes lower. The Hydra fit
sweep (``experiments/fit_sweep.py``): each fit config composes with overrides, and a multirun over
two of them writes one estimate line per run."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from drapejax.io import load_measurement, load_truth

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.experiment
def test_multirun_over_materials_writes_a_folder_and_a_line_per_run(tmp_path):
    results = tmp_path / "sweep.jsonl"
    cmd = [sys.executable, "-m", "experiments.drape_sweep", "--multirun", "mesh=fit", "mesh.spacing_mm=30",
           "mesh.rim_mm=null", "solver=quick", "material=light,mid", f"results={results}",
           f"hydra.sweep.dir={tmp_path / 'runs'}"]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, timeout=900)
    lines = [json.loads(s) for s in results.read_text().splitlines()]
    assert [r["material"] for r in lines] == ["light", "mid"]
    for r in lines:
        assert r["status"] == "at_rest" and r["spacing_mm"] == 30.0 and r["quick"]
        assert load_measurement(r["out"]).has_silhouette
        assert load_truth(r["out"])["mesh"]["seed"] == 0
    light, mid = lines
    assert light["dc"] < mid["dc"] - 0.1, (light["dc"], mid["dc"])


def test_fit_sweep_composes_each_fit_config_with_overrides():
    """``experiments/fit_sweep.py``'s Hydra configs compose for each fit of ``configs/fit`` (the
    refined fit, the network alone, the fine mesh), and an override reaches the composed job. The
    sweep itself, which fits, is the experiment-marked multirun test below."""
    for name, refine in (("default", True), ("no_refine", False), ("fine", True)):
        cmd = [sys.executable, "-m", "experiments.fit_sweep", f"fit={name}", "fit.max_steps=2", "capture=/x",
               "results=/y", "--cfg", "job"]
        text = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True, timeout=300).stdout
        assert f"refine: {str(refine).lower()}" in text and "max_steps: 2" in text and "capture: /x" in text, text


@pytest.mark.experiment
def test_fit_multirun_over_fit_configs_writes_a_line_per_run(shared_data, tmp_path):
    """``experiments/fit_sweep.py`` on one real capture (fabric 2, density known): the refined fit
    (``fit=default``, what ``drapejax estimate`` does, here for two steps) and the network alone
    (``fit=no_refine``); an override of a field applies to every run of the sweep."""
    folder = shared_data / "real_cusick" / "bdp_f02_sample_2_capture_1"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    results = tmp_path / "fits.jsonl"
    cmd = [sys.executable, "-m", "experiments.fit_sweep", "--multirun", "fit=default,no_refine", "fit.max_steps=2",
           f"capture={folder}", f"results={results}", f"hydra.sweep.dir={tmp_path / 'runs'}"]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, timeout=900)
    lines = [json.loads(s) for s in results.read_text().splitlines()]
    assert [r["fit"] for r in lines] == ["default", "no_refine"] and [r["max_steps"] for r in lines] == [2, 2]
    for r in lines:
        assert r["capture"] == str(folder) and r["spacing_mm"] == 20.0 and not r["density_normalized"]
        k1 = [r["params"][f"bend_k1_{d}"] for d in ("warp", "weft", "bias")]
        assert all(math.isfinite(k) and 1e-7 < k < 1e-3 for k in k1), k1
    refined, network = lines
    assert refined["refine"] and refined["status"] in ("converged", "max_steps")
    assert all(math.isfinite(refined["std"][f"bend_k1_{d}"]) for d in ("warp", "weft", "bias"))
    assert not network["refine"] and network["status"] == "not_refined"
    assert all(network["std"][f"bend_k1_{d}"] is None for d in ("warp", "weft", "bias"))
