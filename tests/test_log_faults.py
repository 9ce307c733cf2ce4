"""Faults of the run logs, their readers and recovery, and of the files a run touches (issue 15): a reader accepts
only what the run applied, log-recover keeps every intact step and writes a log its reader reads, a run never writes
into another run's log, an unwritable or full disk stops a run with a clear error, and a pickled policy is refused
without advice to run it. The corrupted logs are written by the real writer from a real recorded run."""
from __future__ import annotations

import dataclasses
import hashlib
import re
import resource
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from mcap.reader import make_reader

from aril_ros import protocol as P
from aril_ros.dataset import load_dagger_dataset
from aril_ros.protocol import StepTag
from aril_ros.registry import adversary_path
from aril_ros.runlog import RunLogError, RunLogWriter, read_run, recover
from tests.conftest import ROOT, episode_stats, free_domain, policy_files, processes_in_domain, run_graph, summary_of

RUN = ("env:=Swimmer-v5", "mode:=sensory", "attack:=random", "eps:=0.1", "episodes:=2", "horizon:=20")
COMPARED = ("true_obs", "obs", "delta", "action", "expert_action", "reward", "physics_state", "stamp_ns")
END_KEYS = {"steps", "episodes_completed", "interrupted", "reason", "missing_steps", "episode_stats"}


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    """One recorded run (2 episodes of 20 steps), its JSON line, and the policy and expert files it ran with."""
    tmp = tmp_path_factory.mktemp("recorded")
    policy, expert = policy_files(tmp, "Swimmer-v5")
    log = tmp / "run.mcap"
    summary = summary_of(run_graph(*RUN, f"policy:={policy}", f"expert:={expert}", f"record:={log}"))
    return log, summary, (policy, expert)


@pytest.fixture
def recorded(recorded_run):
    """The recorded run's log and the arguments naming its files."""
    log, _, (policy, expert) = recorded_run
    return log, (f"policy:={policy}", f"expert:={expert}")


def steps_of(log):
    """The run's metadata and its steps as the recorder hands them to the writer: [(stamp, {topic: cdr bytes})]."""
    topics = {("/" + t).replace("//", "/"): t for t in P.TIMED_STEP_TOPICS}  # a run without timing has no /attack/timing
    with open(log, "rb") as f:
        reader = make_reader(f)
        meta = next(m.metadata for m in reader.iter_metadata() if m.name == "aril_run")
        steps: dict[int, dict[str, bytes]] = {}
        for _, channel, message in reader.iter_messages(topics=list(topics)):
            steps.setdefault(message.log_time, {})[topics[channel.topic]] = message.data
    return meta, list(steps.items())


def write_log(path, meta, steps, extra=None, close=True):
    """Write ``steps`` with the real writer; ``extra`` ({row: [(topic, cdr bytes)]}) goes after its row's step, as a
    second message of that step would; ``close=False`` leaves the log open, as a killed run does, and returns its
    writer."""
    writer = RunLogWriter(path, meta)
    for row, (stamp, messages) in enumerate(steps):
        writer.write_step(stamp, messages)
        for topic, raw in (extra or {}).get(row, []):
            writer._add(topic, stamp, raw)
    if not close:
        return writer
    writer.close(interrupted=False, episodes=[])  # the end record's figures are not what these logs test
    return path


def edited(raw: bytes, **fields) -> bytes:
    """A JointState message with some of its fields replaced."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    msg = deserialize_message(raw, JointState)
    for name, value in fields.items():
        setattr(msg, name, value)
    return serialize_message(msg)


def values(raw: bytes, field="position") -> np.ndarray:
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    return np.array(getattr(deserialize_message(raw, JointState), field))


def with_delta(messages: dict[str, bytes], delta: np.ndarray) -> dict[str, bytes]:
    """The step with another perturbation and the observation it makes (state + delta), so only delta is wrong."""
    state = values(messages[P.STATE])
    return {**messages, P.PERTURBATION: edited(messages[P.PERTURBATION], position=list(delta)),
            P.OBSERVATION: edited(messages[P.OBSERVATION], position=list(state + delta))}


@pytest.mark.slow
def test_readers_refuse_what_the_run_did_not_apply(recorded, tmp_path):
    log, _ = recorded
    meta, steps = steps_of(log)
    assert read_run(write_log(tmp_path / "same.mcap", meta, steps)).tags == read_run(log).tags  # a faithful rewrite
    stamp, messages = steps[5]  # step 0/5
    action = values(messages[P.ACTION], "effort")
    zero = np.zeros(8)
    faults = {
        "second action": ({}, {5: [(P.ACTION, edited(messages[P.ACTION], effort=list(-action)))]},
                          r"step 0/5 has 2 messages on action"),
        "delta beyond eps": (with_delta(messages, np.where(np.arange(8) == 1, 0.15, zero)), {},
                             r"step 0/5 attack/perturbation: delta\[1\] \(.*\) = 0.15, beyond eps 0.1"),
        "delta on a velocity": (with_delta(messages, np.where(np.arange(8) == 4, 0.01, zero)), {},
                                r"step 0/5 attack/perturbation: delta\[4\] \(.*:vel\) = 0.01, on an entry that is "
                                r"not zero-order"),
        "short action row": ({**messages, P.ACTION: edited(messages[P.ACTION], effort=[0.1])}, {},
                             r"step 0/5 action: 1 values where the run's layout has 2"),
        "observation not state + delta": (
            {**messages, P.OBSERVATION: edited(messages[P.OBSERVATION], position=list(values(messages[P.STATE])))}, {},
            r"step 0/5 observation: not sim/state \+ attack/perturbation"),
    }
    for name, (step, extra, message) in faults.items():
        broken = write_log(tmp_path / f"{name}.mcap", meta, [*steps[:5], (stamp, step or messages), *steps[6:]], extra)
        with pytest.raises(RunLogError, match=message):
            read_run(broken)
        with pytest.raises(RunLogError, match=message):
            load_dagger_dataset(broken)
    # a physical step's observation is the moved state's: state + delta on the zero-order entries, physics elsewhere
    physical = {**meta, "mode": "physical"}
    seen = values(messages[P.OBSERVATION])
    for entry, accepted in ((4, True), (1, False)):
        moved = {**messages,
                 P.OBSERVATION: edited(messages[P.OBSERVATION], position=list(seen + (np.arange(8) == entry)))}
        log_of = write_log(tmp_path / f"physical-{entry}.mcap", physical, [*steps[:5], (stamp, moved), *steps[6:]])
        if accepted:
            assert read_run(log_of).obs[5, entry] == seen[entry] + 1
        else:
            with pytest.raises(RunLogError, match=r"step 0/5 observation: not sim/state \+ attack/perturbation on its "
                                                  r"zero-order entries, what a physical step shows the policy"):
                read_run(log_of)
    without = {key: value for key, value in meta.items() if key != "zero_order"}
    for name, broken_meta, message in (("no zero_order", without, "metadata lacks zero_order"),
                                       ("eps not a number", {**meta, "eps": "a lot"}, "metadata is malformed")):
        with pytest.raises(RunLogError, match=message):
            read_run(write_log(tmp_path / f"{name}.mcap", broken_meta, steps))


@pytest.mark.slow
def test_log_recover_refuses_a_closed_log_and_writes_what_msgs_doc_lists(recorded, tmp_path, capsys):
    from aril_ros.cli import main

    log, _ = recorded
    before = log.read_bytes()
    assert main(["log-recover", f"input:={log}", f"out:={tmp_path / 'recovered.mcap'}"]) == 2
    assert f"{log}: a closed, readable run log (40 steps, interrupted: false)" in capsys.readouterr().err
    assert log.read_bytes() == before and not (tmp_path / "recovered.mcap").exists()
    documented = re.search(r"metadata record `aril_run_end` \(written last\): (.*?)\.\n",
                           (ROOT / "msgs_doc" / "README.md").read_text(), re.S)[1]
    assert set(re.findall(r"`(\w+)`", documented)) == END_KEYS == set(read_run(log).end)


@pytest.mark.slow
def test_log_recover_drops_a_step_missing_a_message_and_keeps_the_rest(recorded, tmp_path):
    log, _ = recorded
    meta, steps = steps_of(log)
    stamp, messages = steps[5]
    del messages[P.EXPERT_ACTION]
    cut = tmp_path / "cut.mcap"
    writer = RunLogWriter(cut, meta)  # a killed run's log, written in full but for one message of step 0/5
    for row, (stamp, messages) in enumerate(steps):
        if row == 5:
            for topic, raw in messages.items():
                writer._add(topic, stamp, raw)
        else:
            writer.write_step(stamp, messages)
    recovery = recover(cut, tmp_path / "recovered.mcap")
    assert recovery.steps == 39 and recovery.dropped == {StepTag(0, 5): "step 0/5 misses expert/action"}
    run, original = read_run(tmp_path / "recovered.mcap", allow_interrupted=True), read_run(log)
    assert run.end == {"steps": 39, "episodes_completed": 1, "interrupted": True, "missing_steps": ["0/5"],
                       "reason": "recovered from cut.mcap: 39 steps kept, 1 dropped, 0 damaged or stray parts skipped",
                       "episode_stats": original.end["episode_stats"][1:]}  # the episode kept whole, as recorded
    keep = np.arange(40) != 5
    for name in COMPARED:
        np.testing.assert_array_equal(getattr(run, name), getattr(original, name)[keep], err_msg=name)
    with pytest.raises(RunLogError, match="interrupted"):
        read_run(tmp_path / "recovered.mcap")


@pytest.mark.slow
def test_log_recover_skips_damaged_chunks_and_keeps_every_intact_step_after_them(recorded, tmp_path):
    log, _ = recorded
    data = bytearray(log.read_bytes())
    with open(log, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    original = read_run(log)
    content, length = chunks[3], chunks[len(chunks) // 2]  # one with flipped data, one with a broken length
    data[content.chunk_start_offset + content.chunk_length // 2] ^= 0xFF
    data[length.chunk_start_offset + 1: length.chunk_start_offset + 9] = (2**62).to_bytes(8, "little")
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(RunLogError, match="damaged"):
        read_run(damaged, allow_interrupted=True)
    recovery = recover(damaged, tmp_path / "recovered.mcap")
    lost = np.zeros(len(original.tags), bool)
    for chunk in (content, length):
        lost |= (original.stamp_ns >= chunk.message_start_time) & (original.stamp_ns <= chunk.message_end_time)
    assert 0 < lost.sum() < len(lost) - 10 and recovery.steps == (~lost).sum()
    assert len(recovery.damage) == 2 and all("damaged" in what for what in recovery.damage)
    run = read_run(tmp_path / "recovered.mcap", allow_interrupted=True)
    assert run.tags == [tag for tag, gone in zip(original.tags, lost) if not gone]
    for name in COMPARED:
        np.testing.assert_array_equal(getattr(run, name), getattr(original, name)[~lost], err_msg=name)
    assert sorted(run.end["missing_steps"]) == sorted(str(t) for t, gone in zip(original.tags, lost) if gone)


@pytest.mark.slow
def test_default_record_names_differ_for_runs_started_in_the_same_second(monkeypatch):
    import datetime

    from aril_ros_nodes import orchestrator
    from aril_ros_nodes.orchestrator import GraphConfig, Orchestrator

    class SameSecond(datetime.datetime):
        @classmethod
        def now(cls, tz=None):
            return cls(2026, 11, 24, 1, 2, 3)

    monkeypatch.setattr(orchestrator.datetime, "datetime", SameSecond)
    first, second = (Orchestrator(GraphConfig(env="Swimmer-v5")).record for _ in range(2))
    assert first != second and first.name.startswith("20261124-010203-Swimmer-v5-sensory")


@pytest.mark.slow
def test_a_record_path_that_exists_or_cannot_be_written_stops_the_run_before_any_node(recorded, tmp_path):
    log, policies = recorded
    before = log.read_bytes()
    (tmp_path / "a_file").write_text("")
    for record, error in ((log, f"{log} exists (another run's log?): left untouched; record to a new path"),
                          (tmp_path / "a_file" / "run.mcap",
                           f"cannot create the run log's folder {tmp_path / 'a_file'}: File exists"),
                          ("/proc/run.mcap", "cannot create the run log /proc/run.mcap: No such file or directory")):
        out = run_graph(*RUN, *policies, f"record:={record}")  # no node outlives it (run_graph checks)
        assert out.returncode == 1 and out.stderr.strip().splitlines()[-1] == f"run_graph: error: {error}"
        assert "Traceback" not in out.stderr
    assert log.read_bytes() == before


@pytest.mark.slow
def test_a_full_disk_stops_the_run_with_a_clear_error_and_leaves_its_steps_recoverable(recorded, tmp_path):
    """A file size limit stands in for a full disk: writes past it fail with EFBIG, as with ENOSPC."""
    log, policies = recorded
    limit = log.stat().st_size // 2
    cut = tmp_path / "run.mcap"
    domain = free_domain()

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    out = subprocess.run([sys.executable, str(ROOT / "run_graph.py"), *RUN, *policies, f"record:={cut}",
                          f"domain:={domain}"], capture_output=True, text=True, timeout=180, cwd=ROOT,
                         preexec_fn=small_files)
    assert processes_in_domain(domain) == []
    failed = re.search(rf"run_graph: error: writing the run log {cut} failed after (\d+) steps: File too large\n$",
                       out.stderr)
    assert out.returncode == 1 and failed, out.stderr
    assert "Traceback (most recent call last)" not in out.stderr
    with pytest.raises(RunLogError, match="truncated|cut short"):
        read_run(cut, allow_interrupted=True)
    written = int(failed[1])
    assert recover(cut, tmp_path / "recovered.mcap").steps == written > 0
    run, original = read_run(tmp_path / "recovered.mcap", allow_interrupted=True), read_run(log)
    for name in COMPARED:
        np.testing.assert_array_equal(getattr(run, name), getattr(original, name)[:written], err_msg=name)
    completed = min(written // 20, 2)  # horizon:=20: the episodes the kept steps hold whole
    assert (run.end["steps"], run.end["interrupted"], run.end["episodes_completed"]) == (written, True, completed)
    assert run.episode_stats == original.episode_stats[:completed]


def test_the_domain_lock_directory_is_shared_by_every_user(monkeypatch, tmp_path):
    import tempfile

    from aril_ros_nodes.launcher import allocate_domain

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


@pytest.mark.slow
def test_a_resumed_learner_collects_a_round_again_over_its_killed_attempts_log(recorded, tmp_path, monkeypatch):
    """The graph's writer never writes into an existing file, so the round's log of a killed attempt must go."""
    from aril_ros import collectors, dagger, plugins
    from aril_ros.aril_rounds import RoundAdversary
    from aril_ros.learner_config import LearnerConfig
    from aril_ros.learner_run import LearnerRun

    log, _ = recorded

    def collector(spec):  # stands in for the graph: records exclusively, as RunLogWriter does
        with open(spec.record, "xb") as f:
            f.write(log.read_bytes())
        return spec.record

    monkeypatch.setattr(plugins, "load", lambda group, name: collector)
    cfg = LearnerConfig(env="Swimmer-v5", mode="sensory", source="graph", run_dir=str(tmp_path / "run"))
    run = LearnerRun(cfg, log=lambda *a, **k: None)
    (run.dir / "round-0.mcap").write_bytes(log.read_bytes()[:5000])  # the attempt killed mid-round
    record, part = dagger.collect(collectors.graph, cfg, run, 0, RoundAdversary("none"))
    assert len(part) == 40 and (run.dir / "round-0.mcap").read_bytes() == log.read_bytes()


def sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_the_log_and_the_json_line_record_every_attack_setting_and_the_digest_of_every_acting_file(recorded_run):
    log, summary, (policy, expert) = recorded_run
    run = read_run(log)
    assert run.metadata["attack_settings"] == {"attack": "random", "eps": 0.1, "k": None, "samples": None, "search": 0,
                                               "rescale": False, "seed": 0}  # random reads neither k nor samples
    assert run.metadata["files"] == {"policy": {"path": str(policy.resolve()), "sha256": sha256(policy)},
                                     "expert": {"path": str(expert.resolve()), "sha256": sha256(expert)},
                                     "adversary": None}
    assert summary["attack_settings"] == run.metadata["attack_settings"] and summary["files"] == run.metadata["files"]


@pytest.mark.parametrize("args, iterations", [({"attack": "spsa"}, None), ({"attack": "fgsm_k"}, None),
                                              ({"attack": "spsa", "k": 3, "samples": 2}, (3, 2)),
                                              ({"attack": "fgsm", "k": 4}, (4, None))])
def test_a_run_records_k_and_samples_as_its_attack_runs_them(args, iterations):
    """0 asks for the attack's own default: the log says which that was, read here from the attack itself."""
    from aril_ros.attacks import make_attack
    from aril_ros.envs import layout_of
    from aril_ros.policy import resolve_policy
    from aril_ros_nodes.graph_config import GraphConfig, plan_run

    plan = plan_run(GraphConfig(env="Swimmer-v5", eps=0.1, seed=3, record="off", **args))
    settings = plan.metadata()["attack_settings"]
    if iterations is None:
        expert = resolve_policy("expert", "Swimmer-v5")
        attack = make_attack(args["attack"], layout_of("Swimmer-v5"), 0.1, victim=expert, expert=expert)
        iterations = (attack.steps, getattr(attack, "samples", None))
    assert settings == {"attack": args["attack"], "eps": 0.1, "k": iterations[0], "samples": iterations[1],
                        "search": 0, "rescale": False, "seed": 3}


@pytest.mark.parametrize("named", [False, True])
def test_the_bundled_adversary_is_recorded_by_its_package_path_and_digest(named):
    """Whether the run chose it (the default attack against the bundled learner) or it was named, with its file or
    without: never ``''`` nor this machine's absolute path."""
    from aril_ros.adversary_net import load_adversary
    from aril_ros.policy import policy_file
    from aril_ros_nodes.graph_config import GraphConfig, plan_run

    bundled = adversary_path("Swimmer-v5", "physical")
    for attack_file in ("", str(bundled)) if named else ("",):
        plan = plan_run(GraphConfig(env="Swimmer-v5", mode="physical", attack="aril_a" if named else "",
                                    attack_file=attack_file, search=2 if named else 0, record="off"))
        meta = plan.metadata()
        policy, expert = (policy_file(name, "Swimmer-v5") for name in ("dagger", "expert"))
        assert meta["files"] == {
            "adversary": {"path": "aril_ros/data/adversary/Swimmer-v5-physical.pt", "sha256": sha256(bundled)},
            "policy": {"path": "aril_ros/data/dagger/Swimmer-v5.pt", "sha256": sha256(policy)},
            "expert": {"path": "aril_ros/data/expert/Swimmer-v5.pt", "sha256": sha256(expert)}}
        assert meta["attack_settings"] == {"attack": "aril_a", "eps": load_adversary(bundled).eps, "k": None,
                                           "samples": None, "search": 2 if named else 0, "rescale": False, "seed": 0}


def test_the_end_record_holds_each_episode_s_figures_as_its_steps_sum_to(recorded_run):
    """The recorder takes them once, as it writes the steps; a reader (a graph round's collector) finds them there."""
    log, summary, _ = recorded_run
    run = read_run(log)
    assert run.episode_stats == episode_stats(run) and run.end["episodes_completed"] == 2
    assert [(e.steps, e.done) for e in run.episode_stats] == [(20, True), (20, True)]  # horizon:=20, truncated
    assert summary["returns"] == [round(e.reward, 3) for e in run.episode_stats]


def test_a_log_from_before_the_end_record_held_figures_reads_and_says_it_has_none(recorded, tmp_path):
    from aril_ros.runlog.layout import encoded

    log, _ = recorded
    meta, steps = steps_of(log)
    writer = write_log(tmp_path / "older.mcap", meta, steps, close=False)
    older = read_run(log).end
    del older["episode_stats"]
    writer._writer.add_metadata("aril_run_end", encoded(older))  # as an older aril_ros closed its logs
    writer._writer.finish()
    writer._file.close()
    run = read_run(tmp_path / "older.mcap")
    assert run.tags == read_run(log).tags
    with pytest.raises(RunLogError, match="the log's end record has no episode_stats"):
        run.episode_stats


def test_the_recorder_reads_a_joint_state_s_values_in_place_as_deserialising_does():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    from aril_ros.runlog.cdr import joint_values

    rng = np.random.default_rng(0)
    for _ in range(300):  # names and arrays of every length, empty ones included, shift the CDR alignment
        msg = JointState(name=["n" * int(k) for k in rng.integers(0, 9, rng.integers(0, 20))])
        msg.header.frame_id = "x" * int(rng.integers(0, 12))
        for field in ("position", "velocity", "effort"):
            setattr(msg, field, rng.standard_normal(rng.integers(0, 20)).tolist())
        raw = serialize_message(msg)
        for field in ("position", "velocity", "effort"):
            expected = np.array(getattr(deserialize_message(raw, JointState), field), dtype=np.float64)
            assert joint_values(raw, field).tobytes() == expected.tobytes()
