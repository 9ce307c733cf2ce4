#!/usr/bin/env python3
"""Run the test suite: ``python run_tests.py [pytest arguments]``. Installs what it needs first."""
import sys

from bootstrap import ensure_venv

if __name__ == "__main__":
    ensure_venv()
    import pytest

    code = pytest.main(sys.argv[1:] or ["-q", "tests"])
    sys.exit(0 if code == pytest.ExitCode.OK else int(code))
