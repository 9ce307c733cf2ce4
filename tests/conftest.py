"""Shared fixtures: small random policies for any env, written as real policy files."""
from __future__ import annotations

import os
import tempfile

import pytest
import torch

# pytest-xdist's worker (gw0, gw1, ...) and their number; one process without it
WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:])
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
# A test process never joins another run's ROS graph (the graph tests start real nodes); an id of the
# upper safe range (215-232), whose DDS ports keep clear of Linux's ephemeral ones. The workers of one suite
# count on from their parent's slot, so two of them never share one.
_SLOT = (os.getppid() if "PYTEST_XDIST_WORKER" in os.environ else os.getpid()) + WORKER
os.environ.setdefault("ROS_DOMAIN_ID", str(215 + _SLOT % 18))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# Trainers write a user's files to $ARIL_DATA by default: the tests' go to a folder of their own, never the
# home of whoever runs them (the node processes the graph tests start inherit it).
os.environ["ARIL_DATA"] = tempfile.mkdtemp(prefix="aril_data-tests-")

from aril_ros.policy import MLPPolicy, meta_for_env  # noqa: E402

RUN_DOMAINS = range(1, 102)
"""The ids graph runs of the tests take (the test processes' own are 215-232)."""


def free_domain() -> int:
    """A domain no other aril_ros run holds; released so run_graph.py (domain:=N) can take it. Each worker takes
    from its own share of the ids (every WORKERS-th), so two workers never pick one between release and take."""
    from aril_ros_nodes.orchestrator import GraphError, allocate_domain

    for domain in RUN_DOMAINS[WORKER::WORKERS]:
        try:
            _, lock = allocate_domain(str(domain))
        except GraphError:  # held by another run
            continue
        lock.close()
        return domain
    raise GraphError(f"no free ROS domain id among {RUN_DOMAINS[WORKER::WORKERS]}")


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
