"""aril onboard: expert, DAgger learner and eps into the user data folder, each stage resumed or skipped."""
import json
import os

import pytest

from aril_ros import registry
from aril_ros.onboard import OnboardConfig, onboard
from aril_ros.policy import resolve_policy
from tests.conftest import local_ray

TINY = dict(env="Hopper-v5", expert_steps=300, eval_every=300, rounds=1, episodes=1, calibration_episodes=1,
            final_episodes=2)


@pytest.mark.slow
def test_onboarding_makes_the_names_resolve_and_resumes_instead_of_redoing(tmp_path, monkeypatch):
    monkeypatch.setenv("ARIL_DATA", str(tmp_path / "data"))
    with local_ray():  # one Ray for the four onboardings' calibrations, each of which would start its own
        package = {str(p): p.stat().st_mtime_ns for p in registry.DATA_DIR.rglob("*")}
        lines = []
        summary = onboard(OnboardConfig(**TINY), log=lambda line, **_: lines.append(line))
        home = tmp_path / "data" / "onboard" / "Hopper-v5"
        assert json.loads((home / "onboard.json").read_text()) == summary
        assert summary["expert_return"]["episodes"] == 2 and set(summary["eps"]) == {"sensory", "physical"}
        for name in ("expert", "dagger"):
            assert resolve_policy(name, "Hopper-v5").meta.env_id == "Hopper-v5"
        assert registry.calibrated_eps("Hopper-v5", "physical") == summary["eps"]["physical"]
        assert (home / "expert" / "replay_buffer.pkl").is_file() and (home / "dagger" / "state.json").is_file()
        assert {str(p): p.stat().st_mtime_ns for p in registry.DATA_DIR.rglob("*")} == package

        # run again: every stage is there, nothing is trained or calibrated anew; the trainings' own seconds stay
        again = []
        rerun = onboard(OnboardConfig(**TINY), log=lambda line, **_: again.append(line))
        assert not [line for line in again if "train-" in line or "calibrate-eps" in line], again
        assert rerun["trained_seconds"] == summary["trained_seconds"] and summary["trained_seconds"]["expert"] > 0
        # more expert steps: the expert's training resumes from its checkpoint
        more = []
        onboard(OnboardConfig(**{**TINY, "expert_steps": 600}), log=lambda line, **_: more.append(line))
        assert any("resuming from" in line and "at step 300" in line for line in more)
        # an expert newer than the learner (a better actor kept): the learner and the eps are made anew
        expert = registry.user_path("expert", "Hopper-v5")
        later = registry.user_path("dagger", "Hopper-v5").stat().st_mtime_ns + 10**9
        os.utime(expert, ns=(later, later))
        anew = []
        onboard(OnboardConfig(**{**TINY, "expert_steps": 600}), log=lambda line, **_: anew.append(line))
        assert any("the learner and the eps are made anew" in line for line in anew)
        assert any("[train-learner" in line for line in anew) and any("[calibrate-eps" in line for line in anew)
