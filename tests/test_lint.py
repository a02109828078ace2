"""The code base passes ruff (rules in pyproject.toml's ``[tool.ruff]``), and no library module grows past
the size one reader can hold (600 lines)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PATHS = ["drapejax", "tests", "experiments", "benchmarks"]


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None,
                    reason="ruff is not installed (pip install -e '.[test]' installs it)")
def test_ruff_finds_nothing():
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", *PATHS], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, f"ruff check {' '.join(PATHS)} failed:\n{out.stdout}{out.stderr}"


MAX_MODULE_LINES = 600


def test_no_library_module_over_600_lines():
    long = {str(p.relative_to(ROOT)): n for p in sorted((ROOT / "drapejax").rglob("*.py"))
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, f"library modules over {MAX_MODULE_LINES} lines (split them by job): {long}"
