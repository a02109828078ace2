"""The library, the tests and the README state rules and reasons, not development history.

Measured results and how they were obtained belong in docs/results/ and the experiments' and
benchmarks' READMEs; a "stop N" reference in a docstring, comment or the user guide means
nothing to a reader of the code.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HISTORY = re.compile(r"\bstops? ?-?\d+\b", re.IGNORECASE)


def _occurrences() -> list[str]:
    here = Path(__file__).resolve()
    files = [ROOT / "README.md"]
    for folder in ("drapejax", "tests"):
        files += sorted(p for p in (ROOT / folder).rglob("*") if p.is_file() and p.resolve() != here)
    found = []
    for path in files:
        if "__pycache__" in path.parts:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue  # binary files (packaged models) carry no prose
        for number, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    return found


def test_no_development_history_in_library_tests_or_readme():
    found = _occurrences()
    assert not found, "development-history references ('stop N') found:\n" + "\n".join(found)
