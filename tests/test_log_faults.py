"""Faults of the run logs, their readers and recovery, and of the files a run touches (issue 15): a reader accepts
only what the run applied, log-recover keeps every intact step and writes a log its reader reads, a run never writes
into another run's log, an unwritable or full disk stops a run with a clear error, and a pickled policy is refused
without advice to run it. The corrupted logs are written by the real writer from a real recorded run."""
from __future__ import annotations

import dataclasses

import pytest
import torch


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
