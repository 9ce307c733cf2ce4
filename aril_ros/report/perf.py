"""The report's performance section: every benchmark registered in the ``aril_ros.benchmarks`` entry
points (:mod:`aril_ros.plugins`), run back to back as ``python -m <module> key:=value ...``; each one's
closing JSON line is its figures. One that is not installed or fails is recorded with why."""
from __future__ import annotations

import json
import subprocess
import sys

from .. import plugins
from ..registry import DEFAULT_ENV

GROUP = "aril_ros.benchmarks"


def arguments(steps: int, env: str = DEFAULT_ENV) -> dict[str, list[str]]:
    """The report's arguments of each benchmark it knows, in the order they run (``steps``: the engine's)."""
    return {"engine": [f"env:={env}", f"steps:={steps}"],
            "graph": [f"env:={env}", f"steps:={max(steps // 10, 1000)}", f"bare_steps:={max(steps // 10, 1000)}"],
            "adversary": [f"env:={env}", f"steps:={max(steps * 4, 16384)}"],
            "soak": [f"env:={env}", "episodes:=10", "horizon:=500"]}  # the quick soak: a few minutes


def run_benchmark(name: str, args: list[str]) -> dict:
    """One benchmark's closing JSON line and its command, or ``error`` (not installed, failed, no JSON)."""
    try:
        module = plugins.value(GROUP, name)
    except ValueError as err:
        return {"error": str(err), "command": f"{GROUP}:{name} {' '.join(args)}"}
    command = f"python -m {module} {' '.join(args)}"
    done = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True)
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    if done.returncode or not lines:
        return {"error": (done.stderr.strip().splitlines() or ["no output"])[-1], "command": command}
    return {**json.loads(lines[-1]), "command": command}


def run_benchmarks(steps: int, log, env: str = DEFAULT_ENV) -> dict:
    """The report's benchmarks and any other registered one (with no arguments), each one's figures."""
    known = arguments(steps, env)
    figures = {}
    for name in [*known, *(n for n in plugins.names(GROUP) if n not in known)]:
        args = known.get(name, [])
        log(f"[report] benchmark {name}: {' '.join(args)}", flush=True)
        figures[name] = run_benchmark(name, args)
    return figures
