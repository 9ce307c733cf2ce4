"""The suite's two pytest-xdist workers never pick the same ROS domain for a graph run."""
from __future__ import annotations

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
