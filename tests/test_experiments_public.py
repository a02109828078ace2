"""The experiments use the library's public names only, and the library uses none of theirs (issue 76:
"experiments as a small package of entry points sharing helpers (no sys.path edits, no private
imports)").

Read from the source with ``ast`` (nothing is imported or run): in ``experiments/*.py`` no import of a
private ``drapejax`` module or name, no private attribute (``x._name``, ``getattr(x, "_name")``) other
than on ``self``/``cls`` (library objects reach experiments through variables, e.g. a ``Problem``, so
a check on the imported names alone would miss them), and no ``sys.path`` edits; in ``drapejax/`` no
import of ``experiments`` or ``benchmarks``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = sorted((ROOT / "experiments").glob("*.py"))
LIBRARY = sorted((ROOT / "drapejax").rglob("*.py"))
OWN = ("self", "cls")
PUBLIC_UNDERSCORED = {"_replace", "_asdict", "_fields", "_make", "_field_defaults"}  # namedtuple's public API
OUTSIDE = ("experiments", "benchmarks")


def _private(name: str) -> bool:
    """A leading underscore that is not a dunder."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _drapejax(module: str | None) -> bool:
    return (module or "").split(".")[0] == "drapejax"


def private_uses(source: str) -> list[str]:
    """The private library names, private attributes and ``sys.path`` uses in one module's source."""
    found = []
    for node in ast.walk(ast.parse(source)):
        where = f"line {getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Import):
            for a in node.names:
                if _drapejax(a.name) and any(_private(p) for p in a.name.split(".")):
                    found.append(f"{where}: import {a.name}")
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            if _drapejax(node.module):
                if any(_private(p) for p in node.module.split(".")):
                    found.append(f"{where}: from {node.module} import ...")
                found += [f"{where}: from {node.module} import {a.name}" for a in node.names if _private(a.name)]
            elif node.module == "sys" and any(a.name == "path" for a in node.names):
                found.append(f"{where}: from sys import path")
        elif isinstance(node, ast.Attribute):
            if _private(node.attr) and node.attr not in PUBLIC_UNDERSCORED and not (
                    isinstance(node.value, ast.Name) and node.value.id in OWN):
                found.append(f"{where}: {ast.unparse(node)}")
            elif node.attr == "path" and isinstance(node.value, ast.Name) and node.value.id == "sys":
                found.append(f"{where}: sys.path")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "setattr", "hasattr", "delattr") and len(node.args) >= 2
              and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
              and _private(node.args[1].value) and not (
                  isinstance(node.args[0], ast.Name) and node.args[0].id in OWN)):
            found.append(f"{where}: {ast.unparse(node)}")
    return found


def outside_imports(source: str) -> list[str]:
    """The imports of ``experiments`` or ``benchmarks`` in one module's source."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [f"line {node.lineno}: import {a.name}" for a in node.names if a.name.split(".")[0] in OUTSIDE]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] in OUTSIDE:
            found.append(f"line {node.lineno}: from {node.module} import ...")
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str) and node.args[0].value.split(".")[0] in OUTSIDE
              and ast.unparse(node.func).split(".")[-1] in ("import_module", "__import__")):
            found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


def test_there_are_experiments_and_library_modules():
    assert len(EXPERIMENTS) > 5 and len(LIBRARY) > 20


@pytest.mark.parametrize("path", EXPERIMENTS, ids=lambda p: p.name)
def test_experiment_uses_public_names_only(path):
    found = private_uses(path.read_text())
    assert not found, f"{path.relative_to(ROOT)} uses private library names or sys.path:\n" + "\n".join(found)


def test_library_imports_no_experiment_or_benchmark():
    found = [f"{p.relative_to(ROOT)} {f}" for p in LIBRARY for f in outside_imports(p.read_text())]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("snippet", [
    "from drapejax.refine import _fold_rms",
    "from drapejax.refine import fit, _to_fabric as to_fabric",
    "from drapejax.solve._sparse import term_hessian_coo",
    "import drapejax.solve._sparse as sparse",
    "from drapejax import refine\nrefine._hard_features(1)",
    "import drapejax.refine\ndrapejax.refine._params_at(1, 2)",
    "def f(prob):\n    return prob._split(0)",
    "x = misfits[0]._whiten(f)",
    "getattr(refine, '_fold_rms')(a)",
    "import sys\nsys.path.insert(0, 'experiments')",
    "import sys\nsys.path.append('..')",
    "from sys import path\npath.insert(0, '.')",
])
def test_a_private_use_is_found(snippet):
    assert private_uses(snippet), snippet


def test_public_names_and_own_attributes_pass():
    snippet = ("import sys\nfrom drapejax import refine\nfrom drapejax.solve import term_hessian_coo\n"
               "import drapejax.refine as r\nclass A:\n    def f(self):\n        return self._x, cls._y\n"
               "refine.fold_rms(1); r.hard_features(2); p._replace(a=1); sys.argv; drapejax.__version__\n"
               "from experiments.common import _local_helper\n")
    assert private_uses(snippet) == []


@pytest.mark.parametrize("snippet", [
    "from experiments.common import emit",
    "import experiments.common",
    "import benchmarks.bench_drape as b",
    "importlib.import_module('experiments.common')",
])
def test_a_library_import_of_an_experiment_is_found(snippet):
    assert outside_imports(snippet), snippet


def test_library_imports_of_its_own_pass():
    assert outside_imports("from . import refine\nfrom ..solve import drape\nimport numpy\n"
                           "importlib.import_module('drapejax.refine')\n") == []
