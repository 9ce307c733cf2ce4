"""Shared fixtures: small random policies for any env, written as real policy files."""
from __future__ import annotations

import os
import tempfile

import pytest
import torch

# A test process never joins another run's ROS graph (the graph tests start real nodes); an id of the
# upper safe range (215-232), whose DDS ports keep clear of Linux's ephemeral ones.
os.environ.setdefault("ROS_DOMAIN_ID", str(215 + os.getpid() % 18))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# Trainers write a user's files to $ARIL_DATA by default: the tests' go to a folder of their own, never the
# home of whoever runs them (the node processes the graph tests start inherit it).
os.environ["ARIL_DATA"] = tempfile.mkdtemp(prefix="aril_data-tests-")

from aril_ros.policy import MLPPolicy, meta_for_env  # noqa: E402


def random_policy(env_id: str, seed: int = 0, hidden=(32, 32)) -> MLPPolicy:
    torch.manual_seed(seed)  # test-only: the fixture's weights, not library randomness
    return MLPPolicy(meta_for_env(env_id, hidden=list(hidden), provenance={"made_by": "tests"})).eval()


@pytest.fixture
def make_policy():
    return random_policy


class AnswersOnly:
    """A black box: it answers ``act`` and refuses every other access (weights, gradients)."""

    def __init__(self, policy):
        object.__setattr__(self, "_policy", policy)

    def act(self, obs):
        return self._policy.act(obs)

    def __getattr__(self, name):
        raise AssertionError(f"a black-box attack reached for the victim's {name!r}")
