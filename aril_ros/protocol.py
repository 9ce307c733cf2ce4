"""The graph's step protocol, shared by the ROS nodes, the recorder and the log reader (no rclpy).

Every message of one control step carries the same header: ``stamp`` is the step's sim time and
``frame_id`` is the step tag ``"<episode>/<step>"``, so a step's state, perturbation, observation,
action, expert label and reward join on the tag without guessing. Sim time runs on across episodes
(global step ``g`` has stamp ``g * dt``), so stamps and log times are monotonic over a whole run.
A query-based attack asks the policy about observations of its own (probes): they go out on
``observation`` tagged ``"<episode>/<step>/probe/<k>"`` (:class:`ProbeTag`), which is no step tag, so
the simulator never steps on their answers. msgs_doc/README.md is the human-readable form of this module.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass

from .args import ArgumentError

# Topic names, relative so that ``-r __ns:=/robot1`` namespaces a whole graph.
STATE = "sim/state"  # sensor_msgs/JointState: position = true observation (what the expert labels)
PHYSICS = "sim/physics_state"  # sensor_msgs/JointState: position = full MuJoCo integration state
REWARD = "sim/reward"  # sensor_msgs/JointState: names reward/terminated/truncated, position = values
OBSERVATION = "observation"  # sensor_msgs/JointState: position = the observation the policy sees
PERTURBATION = "attack/perturbation"  # sensor_msgs/JointState: position = delta (observation coords)
ACTION = "action"  # sensor_msgs/JointState: effort = the policy's action
EXPERT_ACTION = "expert/action"  # sensor_msgs/JointState: effort = the expert's action on the true state
TIMING = "attack/timing"  # sensor_msgs/JointState, a run with a timing attack only: names TIMING_NAMES, position
TIMING_NAMES = ("observation_age", "dropped", "action_age")  # the step's timing (aril_ros.timing)
CLOCK = "/clock"  # rosgraph_msgs/Clock: sim time, one message per step
CAMERA = "sim/camera/image/compressed"  # sensor_msgs/CompressedImage (JPEG), every render_every steps; opt-in
READY = "graph/ready"  # std_msgs/String, transient local: a node's name once all its endpoints are matched
PROBE_CLIENT = "attacker_probes"  # the node name of the attacker's probe client: the run admits it (trust model)
RESET_SERVICE = "sim/reset"  # rcl_interfaces/srv/SetParametersAtomically: seed (int), episode (int)
SET_STATE_SERVICE = "sim/set_state"  # rcl_interfaces/srv/SetParametersAtomically: state (double[]), tag

PROBE_BATCHES = "probe_batches"
"""The parameter by which a policy node declares that it answers probe batches (:class:`ProbeTag` with ``rows`` > 1)."""

# Where a run log keeps the probes asked on a topic: apart from the step channels, so a step channel holds
# exactly one message per step, and a replay republishes probes where no policy answers them.
PROBE_CHANNELS = {OBSERVATION: "probe/observation", ACTION: "probe/action"}

# What a step needs before it is complete, in the order the recorder writes it.
STEP_TOPICS = (CLOCK, PHYSICS, STATE, PERTURBATION, OBSERVATION, ACTION, EXPERT_ACTION, REWARD)
TIMED_STEP_TOPICS = (CLOCK, PHYSICS, STATE, PERTURBATION, TIMING, OBSERVATION, ACTION, EXPERT_ACTION, REWARD)
"""A run with a timing attack's step topics: the attacker says, per step, how old the observation it delivered is."""
REWARD_NAMES = ("reward", "terminated", "truncated")

MESSAGE_TYPES = {
    STATE: "sensor_msgs/msg/JointState",
    PHYSICS: "sensor_msgs/msg/JointState",
    REWARD: "sensor_msgs/msg/JointState",
    OBSERVATION: "sensor_msgs/msg/JointState",
    PERTURBATION: "sensor_msgs/msg/JointState",
    ACTION: "sensor_msgs/msg/JointState",
    EXPERT_ACTION: "sensor_msgs/msg/JointState",
    TIMING: "sensor_msgs/msg/JointState",
    CLOCK: "rosgraph_msgs/msg/Clock",
}



def step_topics(timed: bool) -> tuple[str, ...]:
    """A run's step topics: :data:`TIMED_STEP_TOPICS` with a timing attack, else :data:`STEP_TOPICS`."""
    return TIMED_STEP_TOPICS if timed else STEP_TOPICS


CAMERA_TYPE = "sensor_msgs/msg/CompressedImage"  # not a step topic: a step is complete without a frame

# Step topics are reliable and keep everything: the chain runs in lockstep, but a slow recorder
# must throttle the publishers (back-pressure) rather than miss a step.
QOS = {"reliability": "reliable", "history": "keep_all", "durability": "volatile"}


@dataclass(frozen=True, order=True)
class StepTag:
    episode: int
    step: int

    def __str__(self) -> str:
        return f"{self.episode}/{self.step}"

    @classmethod
    def parse(cls, text: str) -> "StepTag":
        try:
            episode, step = text.split("/")
            return cls(int(episode), int(step))
        except ValueError:
            raise ValueError(f"not a step tag (want '<episode>/<step>'): {text!r}") from None


@dataclass(frozen=True, order=True)
class ProbeTag:
    """The frame_id of a probe: the ``index``-th observation put to the policy during ``step`` only to
    read its answer, or of a **probe batch**, ``rows`` of them from the ``index``-th on in one message (their
    values one after the other; a policy node that declares ``probe_batches`` answers them in one message too).
    It has four fields where a step tag has two, so :meth:`StepTag.parse` refuses it."""

    step: StepTag
    index: int
    rows: int = 1

    def __str__(self) -> str:
        return f"{self.step}/probe/{self.index}" + (f"..{self.index + self.rows - 1}" if self.rows > 1 else "")

    @classmethod
    def parse(cls, text: str) -> "ProbeTag":
        try:
            step, mark, index = text.rsplit("/", 2)
            first, batch, last = index.partition("..")
            rows = int(last) - int(first) + 1 if batch else 1
            if mark != "probe" or rows < (2 if batch else 1):
                raise ValueError
            return cls(StepTag.parse(step), int(first), rows)
        except ValueError:
            raise ValueError(f"not a probe tag (want '<episode>/<step>/probe/<k>', or '<episode>/<step>/probe/<k>..<m>' "
                             f"for a batch of probes k to m): {text!r}") from None


def is_probe(frame_id: str) -> bool:
    try:
        ProbeTag.parse(frame_id)
    except ValueError:
        return False
    return True


def probe_rows(frame_id: str) -> int:
    """The observations a message tagged ``frame_id`` holds: a probe batch's rows, else one."""
    return ProbeTag.parse(frame_id).rows if ".." in frame_id else 1


def stamp_ns(global_step: int, dt: float) -> int:
    """Sim time of a global step in nanoseconds (integer, so it is exact and monotonic)."""
    return round(global_step * dt * 1e9)


ROS_VARIABLES = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")


SAFE_DOMAINS = (*range(102), *range(215, 233))
"""ROS domain ids whose DDS ports (7400 + 250 * id and up) keep clear of Linux's ephemeral ports
(32768-60999), as the ROS 2 docs list them; Fast-DDS refuses any id above 232 outright."""


def checked_domain(requested: str) -> int:
    """``domain:=requested`` as an id, or an error saying which ids are allowed and why."""
    if not (requested.isdigit() and int(requested) in SAFE_DOMAINS):
        raise ArgumentError(f"domain:={requested} is not an allowed ROS domain id: auto, 0-101 or 215-232 (ids in "
                            "between share ports with Linux's ephemeral range; Fast-DDS refuses ids above 232)")
    return int(requested)


@contextmanager
def ros_domain(domain: int | str):
    """This process in ROS domain ``domain`` for the block, discovering on this machine alone unless the caller set a
    range: what a node, or a client of one, started in this process joins. The caller's variables come back after."""
    before = {name: os.environ.get(name) for name in ROS_VARIABLES}
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
