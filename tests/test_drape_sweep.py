"""The Hydra drape sweep (``experiments/drape_sweep.py``): a multirun over two fabrics writes one
measurement folder and one JSON line per run, and the softer fabric drapes lower."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from drapejax.io import load_measurement, load_truth

ROOT = Path(__file__).resolve().parents[1]


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
