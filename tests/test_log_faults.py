"""Faults of the run logs, their readers and recovery, and of the files a run touches (issue 15): a reader accepts
only what the run applied, log-recover keeps every intact step and writes a log its reader reads, a run never writes
into another run's log, an unwritable or full disk stops a run with a clear error, and a pickled policy is refused
without advice to run it. The corrupted logs are written by the real writer from a real recorded run."""
from __future__ import annotations

import dataclasses
import stat

import pytest
import torch


def test_the_domain_lock_directory_is_shared_by_every_user(monkeypatch, tmp_path):
    import tempfile

    from aril_ros_nodes.orchestrator import allocate_domain

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    (tmp_path / "aril_ros-domains").mkdir(mode=0o755)  # as an older aril_ros made it
    domain, lock = allocate_domain("auto")
    try:
        assert stat.S_IMODE((tmp_path / "aril_ros-domains").stat().st_mode) == 0o1777
        assert stat.S_IMODE((tmp_path / "aril_ros-domains" / f"{domain}.lock").stat().st_mode) == 0o644
        again, other = allocate_domain("auto")  # the lock is held: another domain
        assert again != domain
        other.close()
    finally:
        lock.close()


def test_a_pickled_policy_is_refused_without_advice_to_run_it(tmp_path):
    from aril_ros.policy import PolicyFileError, load_policy

    marker = tmp_path / "ran"

    @dataclasses.dataclass
    class Payload:
        def __reduce__(self):
            return (marker.touch, ())

    torch.save({"format": "aril_ros.policy", "version": 1, "payload": Payload()}, tmp_path / "evil.pt")
    with pytest.raises(PolicyFileError) as refused:
        load_policy(tmp_path / "evil.pt")
    message = str(refused.value)
    assert message.startswith(f"{tmp_path / 'evil.pt'}: refused for safety: the file holds pickled code or objects "
                              "beyond plain weights")
    assert "weights_only" not in message and "arbitrary code" not in message and not marker.exists()
