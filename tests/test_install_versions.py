"""The install is the one that made the bundled files and tables: the venv holds exactly the versions pinned in
``constraints.txt``, and the versions that decide a trajectory (torch, numpy, mujoco, gymnasium) are the ones the
report's provenance and every table of ``results/`` record. A new release moves every figure silently; this test
makes it loud. Upgrading is a deliberate commit that regenerates the tables: docs/install.md."""
from __future__ import annotations

import json
from importlib import metadata
from pathlib import Path

import pytest

import bootstrap
from aril_ros.provenance import versions

ROOT = Path(__file__).resolve().parent.parent
UPGRADE = ("reinstall with `rm .venv/.aril-stamp && python run_tests.py` (bootstrap installs the pins), or upgrade "
           "deliberately, regenerating the tables in the same commit: docs/install.md")


def pins() -> dict[str, str]:
    lines = (ROOT / "constraints.txt").read_text().splitlines()
    return dict(line.split("==") for line in lines if line and not line.startswith("#"))


def recorded_versions() -> dict[str, dict]:
    """Every ``versions`` record of the report and the tables, by where it was found."""
    found = {}

    def walk(node, where):
        if isinstance(node, dict):
            if isinstance(node.get("versions"), dict):
                found[where] = node["versions"]
            for key, value in node.items():
                walk(value, f"{where}/{key}")
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{where}[{i}]")

    for path in [ROOT / "docs/results/report.json", *sorted((ROOT / "results").glob("*.json"))]:
        walk(json.loads(path.read_text()), str(path.relative_to(ROOT)))
    return found


def without_local_label(version: str) -> str:
    return version.split("+")[0]  # torch's "+cpu": the pin names the release, the CPU build comes from bootstrap


def test_the_venv_holds_exactly_the_pinned_versions():
    wrong = {name: (metadata.version(name), pinned) for name, pinned in pins().items()
             if without_local_label(metadata.version(name)) != pinned}
    assert wrong == {}, f"installed (left) differs from constraints.txt (right); {UPGRADE}"


def test_bootstrap_installs_torch_at_its_pin_first():
    name, version = bootstrap.TORCH.split("==")
    assert pins()[name] == version


@pytest.mark.parametrize("name", ["torch", "numpy", "mujoco", "gymnasium"])
def test_the_versions_that_decide_a_trajectory_are_those_the_tables_were_made_with(name):
    records = recorded_versions()
    assert len(records) > 100  # the report and the four tables, every cell of them
    installed = versions()[name]
    differing = {where: record[name] for where, record in records.items() if record.get(name) != installed}
    assert differing == {}, f"{name} {installed} is installed, but the tables were made with other versions; {UPGRADE}"
    assert without_local_label(installed) == pins()[name]
