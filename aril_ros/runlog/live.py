"""The live view of a graph run (``run_graph.py live:=on``): each step the recorder writes, served as it is written
over Foxglove's WebSocket protocol by the ``foxglove-sdk`` package's server (the ``live`` extra, installed on first
use), to the Foxglove app or any client of that protocol.

Channels, as in the run log (:mod:`aril_ros.runlog.layout`): each step topic under its log channel name, in ``cdr``
with the log's ``ros2msg`` schemas, byte for byte what the nodes published; the probes' channels; the camera frames
when the run renders. Beside them :data:`LIVE_CHANNEL` (JSON, :data:`LIVE_SCHEMA`), what a plot wants per step without
decoding the step topics: episode and step, the perturbation, the action the simulator applied and the expert's, their
disagreement, the reward and the return so far. The layout ``docs/foxglove/aril-layout.json`` plots it; opened on a
recorded log, the same layout's panels that read the step topics show the log (the log has no :data:`LIVE_CHANNEL`).

Log time is the step's sim time, as in the log. Nothing is kept for a viewer that connects late: it sees the steps from
when it subscribed (``live:=wait`` holds the first step until a viewer subscribes).
"""
from __future__ import annotations

from .. import protocol as P
from ..extras import FOXGLOVE, ensure
from ..step import EpisodeStats, disagreement
from .layout import CAMERA_CHANNEL, PROBE_CHANNELS, SCHEMAS, absolute

LIVE_CHANNEL = "/aril/live"
"""The per-step figures a plot reads (JSON)."""
LIVE_SCHEMA = {
    "title": "aril_ros.LiveStep",
    "type": "object",
    "properties": {
        "episode": {"type": "integer"},
        "step": {"type": "integer", "description": "the step within its episode, from 0"},
        "perturbation": {"type": "array", "items": {"type": "number"},
                         "description": "what the attack added to the state (observation or physics), per entry"},
        "action": {"type": "array", "items": {"type": "number"}, "description": "the action the simulator applied"},
        "expert_action": {"type": "array", "items": {"type": "number"},
                          "description": "the expert's action on the true state"},
        "disagreement": {"type": "number", "description": "||action - expert_action||^2"},
        "reward": {"type": "number"},
        "return": {"type": "number", "description": "the episode's return so far"},
    },
}
"""The JSON schema of :data:`LIVE_CHANNEL`'s messages."""


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` (0: a free port; :attr:`url` says which) with the run's channels:
    ``topics`` (the run's step topics, :func:`aril_ros.protocol.step_topics`) and, with ``camera``, the frames."""

    def __init__(self, host: str, port: int, topics: tuple[str, ...], camera: bool):
        foxglove = ensure("foxglove", FOXGLOVE, "the live extra, for run_graph.py live:=")
        self.server = foxglove.start_server(host=host, port=port, name="aril_ros")
        self.host = host

        def ros_channel(name: str, msg_type: str):
            schema = foxglove.Schema(name=msg_type, encoding="ros2msg", data=SCHEMAS[msg_type].encode())
            return foxglove.Channel(name, message_encoding="cdr", schema=schema)

        self.steps = {topic: ros_channel(absolute(topic), P.MESSAGE_TYPES[topic]) for topic in topics}
        self.probes = {topic: ros_channel(channel, P.MESSAGE_TYPES[topic]) for channel, topic in PROBE_CHANNELS.items()}
        self.camera = ros_channel(CAMERA_CHANNEL, P.CAMERA_TYPE) if camera else None
        self.figures = foxglove.Channel(LIVE_CHANNEL, schema=LIVE_SCHEMA)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.server.port}"

    def watched(self) -> bool:
        """Whether a viewer has subscribed to any channel (a viewer subscribes only to what its panels show)."""
        channels = [*self.steps.values(), *self.probes.values(), self.figures, *([self.camera] if self.camera else [])]
        return any(channel.has_sinks() for channel in channels)

    def show_step(self, stamp_ns: int, messages: dict[str, bytes], probes, figures: dict, episode: EpisodeStats) -> None:
        """A written step: its messages (raw CDR by topic), its probes (each a dict of raw CDR by topic, in the
        order asked) and its figures (:func:`aril_ros.runlog.recorder.add_step`'s), ``episode`` holding the
        return so far."""
        for topic, raw in messages.items():
            self.steps[topic].log(raw, log_time=stamp_ns)
        for probe in probes:
            for topic, raw in probe.items():
                self.probes[topic].log(raw, log_time=stamp_ns)
        action, expert = figures["action"], figures["expert_action"]
        self.figures.log({"episode": episode.episode, "step": episode.steps - 1,
                          "perturbation": figures["perturbation"].tolist(), "action": action.tolist(),
                          "expert_action": expert.tolist(), "disagreement": float(disagreement(action, expert)),
                          "reward": float(figures["reward"]), "return": episode.reward}, log_time=stamp_ns)

    def show_frame(self, stamp_ns: int, raw: bytes) -> None:
        if self.camera is not None:
            self.camera.log(raw, log_time=stamp_ns)

    def close(self) -> None:
        self.server.stop()
