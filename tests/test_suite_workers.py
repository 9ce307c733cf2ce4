"""The suite's two pytest-xdist workers: they never pick the same ROS domain for a graph run, and the tests of one
``xdist_group`` (the Ray tests, the users of one shared graph run) go to one of them."""
from __future__ import annotations

import pytest

import tests.conftest as conftest


def test_two_workers_pick_graph_run_domains_from_disjoint_shares(monkeypatch):
    """free_domain releases its lock so that run_graph.py can take the id: two workers asking at once would both
    get the same free id unless each picks from its own share."""
    monkeypatch.setattr(conftest, "WORKERS", 2)
    shares = []
    for worker in (0, 1):
        monkeypatch.setattr(conftest, "WORKER", worker)
        shares.append({conftest.free_domain() for _ in range(3)})
    assert shares[0].isdisjoint(shares[1])


@pytest.mark.xdist_group("one-worker")
def test_a_group_is_in_the_id_loadgroup_schedules_by(request):
    """``--dist loadgroup`` keeps a group on one worker by the ``@<group>`` ending of its tests' ids, which the
    workers report to the scheduler: a group missing there is no group."""
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("runs on the workers of -n 2 --dist loadgroup (run_tests.py's)")
    assert request.node.nodeid.endswith("@one-worker")
