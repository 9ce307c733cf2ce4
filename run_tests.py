#!/usr/bin/env python3
"""Run the test suite: ``python run_tests.py [pytest arguments]``. Installs what it needs first.

The suite runs on three workers (pytest-xdist, ``-n 3 --dist loadgroup``: tests of one ``xdist_group`` share a
worker, e.g. the Ray-cluster tests), one more than the two cores it is made for: about a third of a worker's time
goes to waiting on node start-up, ROS discovery and Ray, not to computing (on an idle 2-core Xeon, 356 s against
427 s with two workers). Other arguments are added to it, and one of their own ``-n`` replaces it (``-n 0``: one
process).
``python run_tests.py -m "not slow"`` is the quick loop: the tests under ~3 s each.
"""
import sys

from bootstrap import ensure_venv

WORKERS = ["-n", "3", "--dist", "loadgroup"]

if __name__ == "__main__":
    ensure_venv()
    import pytest

    args = sys.argv[1:]
    own_workers = any(a.startswith(("-n", "--numprocesses")) for a in args)
    code = pytest.main(["-q", *args] if own_workers else ["-q", *WORKERS, *args])
    sys.exit(0 if code == pytest.ExitCode.OK else int(code))
