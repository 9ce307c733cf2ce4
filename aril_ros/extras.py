"""Optional packages, installed into this Python on first use under the checkout's pins (``constraints.txt``: an
extra's own requirements must not move what made the tables), so that the quick start stays small: each is one of
pyproject.toml's extras, kept equal to it."""
from __future__ import annotations

import fcntl
import importlib
import subprocess
import sys
from pathlib import Path

RAY = "ray==2.60.*"
"""The ``cluster`` extra: sweeps on Ray (:mod:`aril_ros.sweep`)."""
FOXGLOVE = "foxglove-sdk==0.30.*"
"""The ``live`` extra: a graph run served to Foxglove as it runs (:mod:`aril_ros.runlog.live`)."""
MINARI = "minari[hdf5]==0.5.*"
"""The ``export`` extra: run logs as Minari datasets and back (:mod:`aril_ros.export`)."""


def ensure(module: str, requirement: str, purpose: str):
    """``module`` imported, ``requirement`` installed first if it is missing (``purpose``: what it is for, said
    while installing). Processes of one Python take turns (a lock in its prefix): one that imported while another's
    pip was writing the package got it half there (the test suite's workers on a fresh clone, each wanting Ray)."""
    with open(Path(sys.prefix) / ".aril_ros-extras.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return importlib.import_module(module)
        except ModuleNotFoundError:
            print(f"[aril_ros] installing {requirement} ({purpose}; once)", file=sys.stderr, flush=True)
            pins = Path(__file__).resolve().parents[1] / "constraints.txt"  # in a checkout
            subprocess.run([sys.executable, "-m", "pip", "install", "--disable-pip-version-check", "-q", requirement,
                            *(["-c", str(pins)] if pins.exists() else [])], check=True)
            importlib.invalidate_caches()  # the import system listed site-packages before the package was in it
            return importlib.import_module(module)
