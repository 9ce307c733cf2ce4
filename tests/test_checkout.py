"""The checkout is a product: only small products are tracked (issue 37).

A tracked file above ``MAX_FILE`` bytes, or a tracked tree above ``MAX_TREE`` bytes, fails here unless it is
named in ``ALLOWED``, with the reason it is there.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FILE = 5_000_000
MAX_TREE = 80_000_000

# Nothing is above the limits today; an entry names a path and why it stays (issue 14's run directories, the
# last entry, left the tree in four landings: results/tuning-runs.json keeps their figures and commands).
ALLOWED: dict[str, str] = {}


def tracked_sizes() -> dict[str, int]:
    """Every tracked file of HEAD with its size in bytes."""
    try:
        out = subprocess.run(["git", "ls-tree", "-r", "-l", "-z", "HEAD"], cwd=ROOT, capture_output=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    sizes = {}
    for record in out.decode().split("\0"):
        if record:
            info, path = record.split("\t", 1)
            kind, size = info.split()[1], info.split()[3]
            if kind == "blob":
                sizes[path] = int(size)
    return sizes


def allowed(path: str) -> bool:
    return any(path == entry or path.startswith(entry + "/") for entry in ALLOWED)


def test_no_tracked_file_above_the_limit_outside_the_allowed_list():
    big = {path: size for path, size in tracked_sizes().items() if size > MAX_FILE and not allowed(path)}
    assert not big, f"tracked files above {MAX_FILE:,} bytes: {big}; keep products small or name them in ALLOWED"


def test_no_tracked_tree_above_the_limit_outside_the_allowed_list():
    sizes = {path: size for path, size in tracked_sizes().items() if not allowed(path)}
    folders: dict[str, int] = {}
    for path, size in sizes.items():
        parts = path.split("/")[:-1]
        for depth in range(1, len(parts) + 1):
            folder = "/".join(parts[:depth])
            folders[folder] = folders.get(folder, 0) + size
    assert sum(sizes.values()) <= MAX_TREE, f"the tracked tree holds {sum(sizes.values()):,} bytes"
    big = {folder: size for folder, size in folders.items() if size > MAX_TREE}
    assert not big, f"tracked trees above {MAX_TREE:,} bytes: {big}"


def test_every_allowed_entry_is_still_tracked():
    sizes = tracked_sizes()
    stale = [entry for entry in ALLOWED if not any(path == entry or path.startswith(entry + "/") for path in sizes)]
    assert not stale, f"ALLOWED names what is no longer tracked: {stale}; remove it from the list"
