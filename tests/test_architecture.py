"""The house's rules, checked on the code itself: the library never imports rclpy nor the ROS side,
and no module of the library imports itself back through others (no import loop)."""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import aril_ros

LIBRARY = Path(aril_ros.__file__).resolve().parent
MODULES = sorted("aril_ros." + ".".join(p.relative_to(LIBRARY).with_suffix("").parts).removesuffix(".__init__")
                 for p in LIBRARY.rglob("*.py") if p.name != "__main__.py")
ROS_SIDE = ("rclpy", "rcl_interfaces", "sensor_msgs", "std_msgs", "rosgraph_msgs", "aril_ros_nodes", "nodes")


def _run(code: str) -> dict:
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_every_library_module_and_the_non_ros_commands_leave_rclpy_unimported():
    code = f"""
import contextlib, io, json, sys
def ros_side():
    return sorted(m for m in sys.modules if m.split(".")[0] in {ROS_SIDE!r})
for name in {MODULES!r}:
    __import__(name)
from aril_ros.cli import COMMANDS, main
with contextlib.redirect_stdout(io.StringIO()):
    for command in COMMANDS:
        main([command, "--help"])
library = ros_side()
with contextlib.redirect_stdout(io.StringIO()):
    main(["--help"])  # lists the ROS side's commands too: their modules load, rclpy must not
print(json.dumps({{"library": library, "listing": [m for m in ros_side() if not m.startswith("aril_ros_nodes")]}}))
"""
    assert _run(code) == {"library": [], "listing": []}


def test_no_library_file_names_the_ros_side():
    offenders = []
    for path in LIBRARY.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            offenders += [f"{path.name}: {n}" for n in names if n.split(".")[0] in ROS_SIDE]
    assert offenders == []


def _imports(module: str) -> set[str]:
    """The library modules ``module`` imports, at any depth in its code (late imports count too)."""
    path = LIBRARY.joinpath(*module.split(".")[1:])
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        found |= {t for t in targets if t in MODULES and t != module}
    return found


def test_the_library_has_no_import_loop():
    graph = {m: _imports(m) for m in MODULES}
    assert {"aril_ros.step", "aril_ros.attacks"} <= graph["aril_ros.rollout"]  # the walk sees late imports too
    # a package's __init__ gathering its own rooms is not a loop
    graph = {m: {t for t in targets if not t.startswith(m + ".")} for m, targets in graph.items()}
    visiting, done, loops = [], set(), []

    def visit(m):
        if m in visiting:
            loops.append(" -> ".join(visiting[visiting.index(m):] + [m]))
            return
        if m in done:
            return
        visiting.append(m)
        for t in sorted(graph[m]):
            visit(t)
        visiting.pop()
        done.add(m)

    for m in MODULES:
        visit(m)
    assert loops == []


@pytest.mark.parametrize("module", ["aril_ros.step", "aril_ros.registry", "aril_ros.seeds", "aril_ros.protocol",
                                    "aril_ros.runlog"])
def test_the_step_rules_and_the_log_reader_need_no_torch(module):
    assert _run(f"import json, sys, {module}; print(json.dumps({{'torch': 'torch' in sys.modules}}))") == {"torch": False}
