"""Install-on-first-use for the two quick-start commands (standard library only).

``run_graph.py`` and ``run_tests.py`` call :func:`ensure_venv` first. Outside the project's
``.venv`` it creates the venv, installs ``torch==2.13.0`` *before* anything that depends on torch
(an unpinned torch would pull a multi-GB CUDA build), then the project with its test extras, and
re-executes the calling script inside the venv. A stamp file holding the hash of ``pyproject.toml``
skips all of that on later runs, and redoes it when the dependencies change.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = Path(os.environ.get("ARIL_VENV", ROOT / ".venv"))
TORCH = "torch==2.13.0"


def _venv_python() -> Path:
    return VENV / "bin" / "python"


def _wanted_stamp() -> str:
    return hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()


def _install() -> None:
    if not _venv_python().exists():
        print(f"[bootstrap] creating {VENV}", file=sys.stderr, flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    pip = [str(_venv_python()), "-m", "pip", "install", "--disable-pip-version-check", "-q"]
    print(f"[bootstrap] installing {TORCH} (CPU) first, then aril_ros and its dependencies", file=sys.stderr,
          flush=True)
    subprocess.run(pip + [TORCH], check=True)
    subprocess.run(pip + ["-e", f"{ROOT}[test]"], check=True)
    (VENV / ".aril-stamp").write_text(_wanted_stamp())


def ensure_venv() -> None:
    """Make sure the project venv is installed and up to date, then run inside it."""
    stamp = VENV / ".aril-stamp"
    if not stamp.exists() or stamp.read_text() != _wanted_stamp():
        _install()
    if Path(sys.prefix).resolve() != VENV.resolve():
        script = Path(sys.argv[0]).resolve()
        os.execv(str(_venv_python()), [str(_venv_python()), str(script), *sys.argv[1:]])
