"""Files written whole or not at all."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable


def write_atomically(path: str | Path, write: Callable[[Path], object]) -> Path:
    """``path``, filled by ``write`` as a partial file beside it that then replaces it in one step: a reader, a
    crash or a commit made meanwhile (benchmarks/scripts/commit-as-it-goes.sh skips ``*.partial``) never sees half
    a file. The partial file is named for this process, so writers of one path on one node never share it."""
    path = Path(path)
    partial = path.with_name(f"{path.name}.{os.getpid()}.partial")
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)  # a write that failed leaves ``path`` as it was, and nothing beside it
    return path
