"""One JSON line per result: printed, and appended to a file when one is given (survives a kill)."""

import json
from pathlib import Path


def emit(row: dict, out: Path | None) -> None:
    line = json.dumps(row, default=float)
    print(line, flush=True)
    if out is not None:
        with open(out, "a") as f:
            f.write(line + "\n")
