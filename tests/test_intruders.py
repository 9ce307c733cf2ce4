"""Who may take part in a run (issue 15, items 2 and 3): exactly one message per topic per step, and no publisher
but the run's own nodes (or the external policy the user started) on a step topic or service.

The graph cases start a real run and, from the test, join its domain with a foreign node that waits for a given
step tag on ``sim/state`` and then publishes (or a policy node that misbehaves at a given step itself): each must
stop the run naming the culprit, with no process left and the log marked interrupted, or, for a harmless
duplicate, count it and keep the log exact."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from aril_ros import protocol as P
from aril_ros.protocol import StepTag
from aril_ros.runlog import RunLogError, read_run
from tests.conftest import cdr, free_domain, policy_files, ros_env, run_graph, step_messages

INJECT_AT = "0/5"  # the step at which the foreign node joins

MARK = 0.4242  # every value the foreign node sends: none may be in the log
# A foreign node: waits for INJECT_AT on sim/state, then creates its publisher, prints its GID, waits until the run's
# subscribers have matched it and publishes once, with the tag of the step then current (or a malformed one), or
# calls sim/reset; then stays until killed.
INTRUDER = r"""
import sys, time
import rclpy
from sensor_msgs.msg import JointState
from aril_ros_nodes.common import STEP_QOS

topic, frame_id, listeners, at, MARK, name = sys.argv[1:4] + sys.argv[4:5] + [float(sys.argv[5]), sys.argv[6]]
listeners = int(listeners)
rclpy.init()
node = rclpy.create_node(name)
seen = []
node.create_subscription(JointState, "sim/state", lambda msg: seen.append(msg.header.frame_id), STEP_QOS)
while at != "start" and at not in seen:
    rclpy.spin_once(node, timeout_sec=0.05)
if topic == "sim/reset":  # a service: its client's request writer is what the run sees
    from rcl_interfaces.srv import SetParametersAtomically
    from aril_ros_nodes.common import param_msg
    client = node.create_client(SetParametersAtomically, topic)
    mine = [i for i in node.get_publishers_info_by_topic("rq/sim/resetRequest", no_mangle=True)
            if i.node_name == name]
    print("GID", bytes(mine[0].endpoint_gid).hex("."), flush=True)
    client.wait_for_service(timeout_sec=10)
    request = SetParametersAtomically.Request(parameters=[param_msg("seed", 7), param_msg("episode", 0)])
    client.call_async(request)
else:
    pub = node.create_publisher(JointState, topic, STEP_QOS)
    mine = [i for i in node.get_publishers_info_by_topic(topic) if i.node_name == name]
    print("GID", bytes(mine[0].endpoint_gid).hex("."), flush=True)
    if at == "start":  # there before the run: it need not send anything to be refused
        time.sleep(120)
    deadline = time.monotonic() + 10
    while pub.get_subscription_count() < listeners and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.001)
    msg = JointState(name=["a"] * 6, position=[MARK] * 6, effort=[MARK] * 6)
    msg.header.frame_id = frame_id if frame_id != "current" else seen[-1]
    pub.publish(msg)
print("published", flush=True)
time.sleep(60)
"""

# The external policy of a run, correct but at INJECT_AT: "twice" answers twice with the same bytes (a harmless
# duplicate), "differs" answers a second time with another action.
TWICE = r"""
import sys
import numpy as np
import rclpy
from sensor_msgs.msg import JointState
from aril_ros_nodes.common import STEP_QOS

behaviour, at = sys.argv[1], sys.argv[2]
rclpy.init()
node = rclpy.create_node("my_policy")
pub = node.create_publisher(JointState, "action", STEP_QOS)

def on_observation(msg):
    action = np.tanh(np.asarray(msg.position[:2]))
    pub.publish(JointState(header=msg.header, effort=action.tolist()))
    if msg.header.frame_id == at:
        pub.publish(JointState(header=msg.header, effort=(action if behaviour == "twice" else -action).tolist()))

node.create_subscription(JointState, "observation", on_observation, STEP_QOS)
rclpy.spin(node)
"""


def run_with(script: str, script_args, tmp_path, *args):
    """A Swimmer run of one long episode (stopped early when the fix works) beside ``script`` in its domain;
    returns the run's output and what the script printed."""
    domain = free_domain()
    other = subprocess.Popen([sys.executable, "-c", script, *script_args], env=ros_env(domain),
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        printed = other.stdout.readline() if "start" in script_args else ""  # there before the run: wait for it
        policy, expert = policy_files(tmp_path, "Swimmer-v5")
        out = run_graph("env:=Swimmer-v5", "mode:=sensory", "episodes:=1", f"expert:={expert}",
                        f"record:={tmp_path / 'run.mcap'}", "step_timeout:=20", *args, domain=domain,
                        besides=[other.pid])
    finally:
        other.kill()
        printed += other.communicate()[0]
    return out, printed


def intrude(tmp_path, topic: str, frame_id: str, listeners: int, at: str = INJECT_AT, name: str = "intruder"):
    policy, _ = policy_files(tmp_path, "Swimmer-v5")
    out, printed = run_with(INTRUDER, [topic, frame_id, str(listeners), at, str(MARK), name], tmp_path,
                            f"policy:={policy}", "horizon:=1000")
    gid = re.search(r"GID (\S+)", printed)
    assert gid, printed
    return out, gid.group(1)


@pytest.mark.slow
@pytest.mark.parametrize("topic, frame_id, listeners", [
    (P.ACTION, "current", 2),  # (a) an action with the current step tag: the simulator and the recorder listen
    (P.OBSERVATION, "current", 2),  # (b) an observation: the policy and the recorder
    (P.ACTION, "garbage", 2),  # (c) a malformed frame_id
    (P.RESET_SERVICE, "", 0),  # a service call: a reset in the middle of the episode
])
def test_a_foreign_publisher_stops_the_run_named_and_the_log_is_interrupted(topic, frame_id, listeners, tmp_path):
    out, gid = intrude(tmp_path, topic, frame_id, listeners)
    assert out.returncode == 1, out.stderr
    kind = "service" if topic == P.RESET_SERVICE else "topic"
    assert re.search(rf"intruder on {kind} /{topic}: node '/intruder' \(GID {re.escape(gid)}\)", out.stderr), \
        out.stderr
    assert "Traceback" not in out.stderr
    run = read_run(tmp_path / "run.mcap", allow_interrupted=True)
    assert run.end["interrupted"] is True and "intruder" in run.end["reason"]
    assert len(run.tags) < 1000  # stopped long before the episode's end (the recorder may lag the simulator)
    assert not np.any(run.obs == MARK) and not np.any(run.action == MARK)  # nothing of it in the log
    with pytest.raises(RunLogError, match="interrupted"):
        read_run(tmp_path / "run.mcap")


@pytest.mark.slow
def test_a_node_passing_for_one_of_the_run_s_nodes_is_refused_before_the_first_step(tmp_path):
    out, gid = intrude(tmp_path, P.STATE, "current", 0, at="start", name="expert")
    assert out.returncode == 1, out.stderr
    assert re.search(rf"more than one node named expert in the run's domain.*node '/expert' \(GID {re.escape(gid)}\) "
                     "on topic /sim/state", out.stderr), out.stderr
    run = read_run(tmp_path / "run.mcap", allow_interrupted=True)
    assert run.end["interrupted"] is True and len(run.tags) == 0


@pytest.mark.slow
def test_a_byte_identical_second_action_is_counted_and_the_log_stays_exact(tmp_path):
    out, _ = run_with(TWICE, ["twice", INJECT_AT], tmp_path, "policy:=external", "horizon:=20")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["duplicates"] == 1
    run = read_run(tmp_path / "run.mcap")  # complete, one message per topic per step
    assert len(run.tags) == 20
    np.testing.assert_array_equal(run.action, np.tanh(run.obs[:, :2]))


@pytest.mark.slow
def test_a_different_second_action_is_a_fault_naming_step_topic_and_publisher(tmp_path):
    out, _ = run_with(TWICE, ["differs", INJECT_AT], tmp_path, "policy:=external", "horizon:=20")
    assert out.returncode == 1, out.stderr
    assert re.search(rf"step {INJECT_AT}: a second message on action, different from the first .*"
                     r"from node '/my_policy' \(GID [0-9a-f.]+\)", out.stderr), out.stderr
    run = read_run(tmp_path / "run.mcap", allow_interrupted=True)
    assert run.end["interrupted"] is True and len(run.tags) <= 6  # the steps before it, and 0/5 as applied
    np.testing.assert_array_equal(run.action, np.tanh(run.obs[:, :2]))


# ------------------------------------------------------------------------------ the recorder alone (no ROS)
def recorder_with_steps(n: int):
    from aril_ros.runlog import StepRecorder

    recorder = StepRecorder(None)
    recorder.start_episode(0)
    steps = [step_messages(StepTag(0, t), 1000 * t, done=t == n - 1) for t in range(n)]
    return recorder, steps


def test_the_recorder_counts_identical_copies_and_never_reopens_a_written_step():
    recorder, steps = recorder_with_steps(3)
    for topic, raw in steps[0].items():
        recorder.on_message(topic, raw)
    assert recorder.steps_written == 1
    recorder.on_message(P.ACTION, steps[0][P.ACTION])  # a late copy of a written step
    recorder.on_message(P.CLOCK, steps[0][P.CLOCK])
    recorder.on_message(P.ACTION, steps[1][P.ACTION])
    recorder.on_message(P.ACTION, steps[1][P.ACTION])  # a copy while its step is open
    for topic, raw in steps[1].items():
        if topic != P.ACTION:
            recorder.on_message(topic, raw)
    for topic, raw in steps[2].items():
        recorder.on_message(topic, raw)
    assert recorder.steps_written == 3 and recorder.episode_done and recorder.duplicates == 3
    assert recorder.pending == {}  # nothing left waiting: no stall


@pytest.mark.parametrize("written", [True, False])
def test_the_recorder_refuses_a_different_second_message_for_a_step(written):
    from aril_ros.runlog import StepFault

    recorder, steps = recorder_with_steps(2)
    other = step_messages(StepTag(0, 0), 0, done=True)[P.REWARD]  # same tag, other bytes
    for topic, raw in steps[0].items():
        if written or topic != P.EXPERT_ACTION:
            recorder.on_message(topic, raw)
    with pytest.raises(StepFault, match="step 0/0: a second message on sim/reward, different from the first "
                                        + ("\\(the step was written already" if written else "\\(the step has one")):
        recorder.on_message(P.REWARD, other)


def test_a_malformed_frame_id_is_a_fault_naming_the_topic():
    from aril_ros_nodes.common import step_header
    from aril_ros.runlog import StepFault

    recorder, _ = recorder_with_steps(1)
    header = step_header(StepTag(0, 0), 0)
    header.frame_id = "garbage"
    with pytest.raises(StepFault, match="a message on action with a malformed frame_id: not a step tag"):
        recorder.on_message(P.ACTION, cdr(header, ["u"], effort=[0.5]))
