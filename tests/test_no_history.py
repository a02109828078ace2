"""The library, the tests, the READMEs and the docs state rules and reasons, not development history.

Measured results and how they were obtained belong in dated pages under docs/results/, beside the
commands that reproduce them; the experiments' and benchmarks' READMEs are user guides. A "stop N"
reference in a docstring, comment, user guide or results page means nothing to a reader.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HISTORY = re.compile(r"\bstops? ?-?\d+\b", re.IGNORECASE)
# Data files under these folders hold recorded numbers, not prose.
DATA_SUFFIXES = {".json", ".jsonl"}


def _files() -> list[Path]:
    here = Path(__file__).resolve()
    files = [ROOT / "README.md"]
    for folder in ("drapejax", "tests"):
        files += sorted(p for p in (ROOT / folder).rglob("*") if p.is_file() and p.resolve() != here)
    for folder in ("experiments", "benchmarks", "docs"):
        files += sorted(p for p in (ROOT / folder).rglob("*")
                        if p.is_file() and p.suffix.lower() not in DATA_SUFFIXES)
    return [p for p in files if "__pycache__" not in p.parts]


def _occurrences() -> list[str]:
    found = []
    for path in _files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue  # binary files (packaged models, figures) carry no prose
        for number, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    return found


def test_the_scan_covers_the_guides_and_the_results_pages():
    files = set(_files())
    for path in ("README.md", "experiments/README.md", "benchmarks/README.md"):
        assert ROOT / path in files
    assert any(p.parent == ROOT / "docs" / "results" and p.suffix == ".md" for p in files)
    assert not any(p.suffix in DATA_SUFFIXES and p.parts[len(ROOT.parts)] == "docs" for p in files)


def test_no_development_history_in_library_tests_readmes_or_docs():
    found = _occurrences()
    assert not found, "development-history references ('stop N') found:\n" + "\n".join(found)
