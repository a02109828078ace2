"""One JSON line per result: printed, and appended to a file when one is given (survives a kill);
``read`` gives a file of such lines back."""

import json
from pathlib import Path


def emit(row: dict, out: Path | None) -> None:
    line = json.dumps(row, default=float)
    print(line, flush=True)
    if out is not None:
        with open(out, "a") as f:
            f.write(line + "\n")


def read(path: Path) -> list[dict]:
    """The rows of a file of JSON lines (blank lines skipped)."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
