"""What a run log holds and how it is laid out: the one place its channels, schemas and records are named.

A run log (``runs/*.mcap``) is a ROS 2 bag in MCAP, readable by ``rosbags`` (``AnyReader``), ``mcap_ros2`` and
Foxglove:

- header profile ``ros2``; schemas ``sensor_msgs/msg/JointState`` and ``rosgraph_msgs/msg/Clock`` (:data:`SCHEMAS`)
  in ``ros2msg`` encoding; messages in ``cdr``, byte for byte as the nodes published them;
- one channel per step topic (:data:`aril_ros.protocol.STEP_TOPICS`) with rosbag2's ``offered_qos_profiles``
  metadata (:data:`QOS_YAML`); with ``run_graph.py render:=true`` also ``/sim/camera/image/compressed``
  (``sensor_msgs/msg/CompressedImage``, JPEG, stamped and tagged like its step, written right after its step),
  which Foxglove shows as video beside the state plots;
- log time = publish time = the step's sim time, so log times are monotonic and a player paces by sim time; each
  step's messages are written together, in ``STEP_TOPICS`` order, once the step is complete, as one chunk
  (:class:`aril_ros.runlog.stream.ChunkStreamWriter`), and the file is flushed after every step (a killed run
  loses no complete step);
- the probes of a query-based attack (observations put to the policy only to read its answer, tagged
  ``"<episode>/<step>/probe/<k>"``, or ``"<episode>/<step>/probe/<k>..<m>"`` for a probe batch, probes k to m in
  one message) on channels of their own, ``/probe/observation`` and ``/probe/action``
  (:data:`aril_ros.protocol.PROBE_CHANNELS`), byte for byte as published on ``observation`` and ``action``, right
  after their step at its log time, in the order asked; the step channels hold the steps alone;
- metadata :data:`RUN` at the start: env, mode, attack, eps, seed, episodes, the observation layout with its
  zero-order entries, ``attack_settings`` (every setting of the attack as it ran) and ``files`` (the policy, the
  expert and the adversary that acted, each its path and SHA-256, or null), policy and expert provenance, as JSON
  strings; and :data:`END` at the end: ``steps``, ``episodes_completed``, ``interrupted``, ``reason``,
  ``missing_steps`` and ``episode_stats`` (each completed episode's :class:`aril_ros.step.EpisodeStats` fields).
  A file without :data:`END` or without its summary was cut short: the reader refuses it, recovery rewrites its
  intact steps into a valid log. msgs_doc/README.md ("Run logs") is the human-readable form of this layout.
"""
from __future__ import annotations

import json

from .. import protocol as P

RUN = "aril_run"
"""The metadata record written first: what the run was (its values JSON-encoded)."""
TIMING_KEY = "timing"
"""The key of :data:`RUN` a run with a timing attack has: its budget and chooser (``delay``, ``drop``,
``action_delay``, ``chooser``, a learned one's ``file``); its steps then have ``attack/timing`` too (:func:`aril_ros.protocol.step_topics`)."""
END = "aril_run_end"
"""The metadata record written last: how the run ended."""

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
SCHEMAS = {
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n"
        + _HEADER + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
    P.CAMERA_TYPE: (
        "std_msgs/Header header\nstring format\nuint8[] data\n"
        + _HEADER + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
    "rosgraph_msgs/msg/Clock": (
        "builtin_interfaces/Time clock\n" + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
}
"""Each message type's ``ros2msg`` schema: its ``.msg`` text with its dependencies."""

# rosbag2's (Jazzy) serialisation of the publishers' QoS: reliable, keep all, volatile.
QOS_YAML = (
    "- history: keep_all\n  depth: 0\n  reliability: reliable\n  durability: volatile\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: automatic\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false\n"
)


def absolute(topic: str) -> str:
    """A topic's channel name in the log."""
    return topic if topic.startswith("/") else "/" + topic


STEP_CHANNELS = {absolute(topic): topic for topic in P.TIMED_STEP_TOPICS}
"""Every step topic's channel (a run without a timing attack has no ``/attack/timing``)."""
PROBE_CHANNELS = {absolute(channel): topic for topic, channel in P.PROBE_CHANNELS.items()}
"""Each probe channel and the step topic its messages were published on."""
CAMERA_CHANNEL = absolute(P.CAMERA)
VALUES = {P.PHYSICS: "position", P.STATE: "position", P.PERTURBATION: "position", P.OBSERVATION: "position",
          P.ACTION: "effort", P.EXPERT_ACTION: "effort", P.REWARD: "position", P.TIMING: "position"}
"""The field of each step topic's JointState that holds its values."""

DELTA_TOLERANCE = 1e-9
"""How far a logged ``|delta|`` may exceed eps. The attacks clip exactly (:meth:`aril_ros.attacks.Attack.project`)
and eps round-trips exactly through the metadata's JSON, so this spares only another writer's float noise."""


class RunLogError(ValueError):
    """A file is not an aril_ros run log, was cut short or damaged, breaks a rule of its run, or cannot be written."""


def encoded(record: dict) -> dict[str, str]:
    """A metadata record as MCAP stores it: every value a string, JSON unless it is one already."""
    return {key: value if isinstance(value, str) else json.dumps(value) for key, value in record.items()}


def decoded(record: dict[str, str]) -> dict:
    """A metadata record's values as written (a string that is no JSON is a string as it was)."""
    return {key: maybe_json(value) for key, value in record.items()}


def maybe_json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text
