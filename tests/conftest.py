"""Shared fixtures: small random policies for any env, written as real policy files."""
from __future__ import annotations

import os

import pytest
import torch

# A test process never joins another run's ROS graph (the graph tests start real nodes).
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from aril_ros.envs import layout_of  # noqa: E402
from aril_ros.policy import MLPPolicy, PolicyMeta  # noqa: E402


def random_policy(env_id: str, seed: int = 0, hidden=(32, 32)) -> MLPPolicy:
    layout = layout_of(env_id)
    torch.manual_seed(seed)  # test-only: the fixture's weights, not library randomness
    meta = PolicyMeta(
        env_id=env_id,
        obs_dim=layout.obs_dim,
        act_dim=layout.act_dim,
        action_low=list(layout.action_low),
        action_high=list(layout.action_high),
        hidden=list(hidden),
        provenance={"made_by": "tests"},
    )
    return MLPPolicy(meta).eval()


@pytest.fixture
def make_policy():
    return random_policy
