"""A user's own files: written to the user data folder ($ARIL_DATA), never into the installed package, and
found by name where nothing is bundled."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aril_ros import registry
from aril_ros.policy import PolicyFileError, resolve_policy, save_policy

from .conftest import random_policy


def package_files() -> dict[str, float]:
    return {str(p): p.stat().st_mtime_ns for p in registry.DATA_DIR.rglob("*")}


@pytest.fixture
def user_data(tmp_path, monkeypatch):
    monkeypatch.setenv("ARIL_DATA", str(tmp_path / "aril-data"))
    return tmp_path / "aril-data"


def test_a_name_resolves_to_the_users_file_where_nothing_is_bundled(user_data):
    with pytest.raises(PolicyFileError, match=r"no expert for Hopper-v5 \(looked for .*aril-data/expert/Hopper-v5.pt\)"
                                              r".*`aril train-expert env:=Hopper-v5`"):
        resolve_policy("expert", "Hopper-v5")
    mine = random_policy("Hopper-v5")
    save_policy(mine, registry.user_path("expert", "Hopper-v5"))
    obs = np.ones(11)
    np.testing.assert_array_equal(resolve_policy("expert", "Hopper-v5").act(obs), mine.act(obs))
    # where one is bundled, the name keeps meaning it: a user's file never changes the bundled envs' figures
    save_policy(random_policy("Swimmer-v5"), registry.user_path("expert", "Swimmer-v5"))
    assert registry.bundled_file("expert", "Swimmer-v5") == registry.bundled_path("expert", "Swimmer-v5")
    assert "keeps meaning" in registry.shadowed_by_bundled("expert", "Swimmer-v5",
                                                           registry.user_path("expert", "Swimmer-v5"))
    assert registry.shadowed_by_bundled("expert", "Hopper-v5", registry.user_path("expert", "Hopper-v5")) is None


def test_the_default_user_folder_is_under_home(monkeypatch, tmp_path):
    monkeypatch.delenv("ARIL_DATA")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert registry.user_data_dir() == tmp_path / ".local" / "share" / "aril_ros"


def test_calibrated_eps_falls_back_to_the_users_calibration(user_data):
    with pytest.raises(ValueError, match=r"no calibrated eps for Hopper-v5 sensory .*pass eps:=<value>.*"
                                         r"aril calibrate-eps envs:=Hopper-v5 modes:=sensory policy:="):
        registry.calibrated_eps("Hopper-v5", "sensory")
    user_data.mkdir(parents=True)
    registry.user_calibration().write_text(json.dumps(
        {"rows": [{"env": "Hopper-v5", "mode": "sensory", "chosen_eps": 0.02},
                  {"env": "HalfCheetah-v5", "mode": "sensory", "chosen_eps": 0.5}]}))
    assert registry.calibrated_eps("Hopper-v5", "sensory") == 0.02
    assert registry.calibrated_eps("HalfCheetah-v5", "sensory") == 0.04  # the bundled row comes first


@pytest.mark.slow
def test_trainers_write_to_the_user_folder_never_into_the_package(user_data):
    """train-expert, train-bc and calibrate-eps with no out:=, as a user runs them."""
    before = package_files()
    env = {**os.environ, "ARIL_DATA": str(user_data)}
    commands = [
        ["train-expert", "env:=Hopper-v5", "steps:=300", "eval_every:=300", "eval_episodes:=1"],
        ["train-bc", "env:=Hopper-v5", "episodes:=1", "epochs:=1"],
        ["calibrate-eps", "envs:=Hopper-v5", "modes:=sensory", "policy:=bc", "grid:=0.01", "episodes:=1",
         "horizon:=20", "workers:=1"],
    ]
    for command in commands:
        done = subprocess.run([sys.executable, "-m", "aril_ros", *command], env=env, capture_output=True, text=True,
                              cwd=user_data.parent, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
    assert (user_data / "expert" / "Hopper-v5.pt").is_file() and (user_data / "bc" / "Hopper-v5.pt").is_file()
    assert registry.calibrated_eps("Hopper-v5", "sensory") == 0.01
    assert package_files() == before
    # and the names now resolve there
    resolve_policy("bc", "Hopper-v5")
    assert Path(resolve_policy("expert", "Hopper-v5").meta.provenance["command"]).name.startswith("aril train-expert")
