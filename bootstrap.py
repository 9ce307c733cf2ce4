"""Install-on-first-use for the two quick-start commands (standard library only).

``run_graph.py`` and ``run_tests.py`` call :func:`ensure_venv` first. Outside the project's
``.venv`` it creates the venv, installs ``torch==2.13.0`` *before* anything that depends on torch
(an unpinned torch would pull a multi-GB CUDA build), then the project with its test extras, both held
to ``constraints.txt`` (the versions that made the bundled files and tables), and re-executes the calling
script inside the venv. A stamp file holding the hash of ``pyproject.toml`` and ``constraints.txt`` skips
all of that on later runs, and redoes it when either changes.
"""
from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = Path(os.environ.get("ARIL_VENV", ROOT / ".venv"))
TORCH = "torch==2.13.0"
CONSTRAINTS = ROOT / "constraints.txt"


def _venv_python() -> Path:
    return VENV / "bin" / "python"


def _wanted_stamp() -> str:
    digest = hashlib.sha256()
    for name in ("pyproject.toml", CONSTRAINTS.name):
        digest.update((ROOT / name).read_bytes())
    return digest.hexdigest()


def _install() -> None:
    import venv  # only here: the common path (already installed) should start fast

    if not _venv_python().exists():
        print(f"[bootstrap] creating {VENV}", file=sys.stderr, flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    pip = [str(_venv_python()), "-m", "pip", "install", "--disable-pip-version-check", "-q", "-c", str(CONSTRAINTS)]
    print(f"[bootstrap] installing {TORCH} (CPU) first, then aril_ros and its dependencies at the versions of "
          f"{CONSTRAINTS.name}", file=sys.stderr, flush=True)
    subprocess.run(pip + [TORCH], check=True)
    subprocess.run(pip + ["-e", f"{ROOT}[test]"], check=True)
    (VENV / ".aril-stamp").write_text(_wanted_stamp())


def exit_on_interrupt(message: str) -> None:
    """Until the caller hands SIGINT on: Ctrl-C prints ``message`` and exits 130, without the traceback of
    whatever import it cut short. Unblocks SIGINT, which :func:`ensure_venv` holds blocked across its re-exec, so
    a Ctrl-C that came while the venv's interpreter started is answered here."""
    def interrupted(signum, frame):
        print(message, file=sys.stderr, flush=True)
        os._exit(130)

    signal.signal(signal.SIGINT, interrupted)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def ensure_venv() -> None:
    """Make sure the project venv is installed and up to date, then run inside it."""
    stamp = VENV / ".aril-stamp"
    if not stamp.exists() or stamp.read_text() != _wanted_stamp():
        _install()
    if Path(sys.prefix).resolve() != VENV.resolve():
        script = Path(sys.argv[0]).resolve()
        # A blocked signal stays pending across exec: a Ctrl-C during the new interpreter's start-up waits for the
        # script's first lines (exit_on_interrupt) instead of ending it with a traceback from its site imports.
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        os.execv(str(_venv_python()), [str(_venv_python()), str(script), *sys.argv[1:]])
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # the re-executed process takes Ctrl-C again
