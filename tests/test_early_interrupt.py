"""Ctrl-C in the first second of ``python run_graph.py``: while bootstrap re-executes it in the venv and while it
imports torch, it ends with one line and exit 130, not a KeyboardInterrupt traceback from inside an import.

The script is started with the interpreter the venv was made from, as a user's ``python run_graph.py`` is, so
bootstrap re-executes it (with SIGINT held blocked across the exec). Before the script's first line the
interpreter's own start-up cannot answer Ctrl-C in one line; the signal is sent once the re-exec shows."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
VENV_PYTHON = str(Path(sys.prefix) / "bin" / "python")  # what bootstrap.ensure_venv execs (ARIL_VENV below)


def argv_of(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    except FileNotFoundError:
        return []


@pytest.mark.slow
@pytest.mark.parametrize("after_start", [0.25, 0.5])
def test_ctrl_c_before_the_run_began_is_one_line_and_exit_130(after_start):
    base_python = str(Path(sys.base_prefix) / "bin" / f"python{sys.version_info.major}.{sys.version_info.minor}")
    assert Path(base_python).is_file() and base_python != VENV_PYTHON  # the interpreter the venv was made from
    started = time.monotonic()
    proc = subprocess.Popen([base_python, str(ROOT / "run_graph.py"), "mode:=sensory", "env:=Swimmer-v5",
                             "episodes:=1", "horizon:=10", "record:=off"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "ARIL_VENV": sys.prefix})
    try:
        while argv_of(proc.pid)[:1] != [VENV_PYTHON] and proc.poll() is None:
            time.sleep(0.01)  # bootstrap has not re-executed yet
        time.sleep(max(0.0, started + after_start - time.monotonic()))
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert (proc.returncode, out, err) == (130, "", "run_graph: interrupted before the run began\n")
