"""run_graph.py live:=: a real graph run served over Foxglove's WebSocket protocol (foxglove-sdk's server), watched by
a client of that protocol written here from its specification: every step of every step topic and every camera frame
arrives, byte for byte what the run log holds, and the per-step figures add up to the episodes' returns."""
from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections import defaultdict

import numpy as np
import pytest

from aril_ros.runlog.layout import CAMERA_CHANNEL, STEP_CHANNELS
from aril_ros.runlog.live import LIVE_CHANNEL
from tests.conftest import policy_files, run_graph, summary_of

SUBPROTOCOL = "foxglove.sdk.v1"
"""The protocol version foxglove-sdk 0.30's server speaks (it refuses the older ``foxglove.websocket.v1``)."""
MESSAGE_DATA = 0x01
"""The opcode of a binary frame carrying one message: then u32 subscription id, u64 log time, the payload."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Viewer(threading.Thread):
    """Connects to ``ws://127.0.0.1:<port>`` as soon as it answers, subscribes to every advertised channel, and keeps
    each message's (log time, payload) by topic until the server goes away."""

    def __init__(self, port: int, wait: float = 120.0):
        super().__init__(daemon=True)
        self.port, self.wait = port, wait
        self.received: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
        self.advertised: dict[int, dict] = {}
        self.error: BaseException | None = None

    def run(self) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect

        try:
            deadline = time.monotonic() + self.wait
            while True:
                try:
                    ws = connect(f"ws://127.0.0.1:{self.port}", subprotocols=[SUBPROTOCOL], open_timeout=5)
                    break
                except OSError:  # the run has not started serving yet
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.2)
            with ws:
                while not self.advertised:
                    message = json.loads(ws.recv())
                    if message["op"] == "advertise":
                        self.advertised = {channel["id"]: channel for channel in message["channels"]}
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": channel, "channelId": channel} for channel in self.advertised]}))
                try:
                    while True:
                        frame = ws.recv()
                        if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                            _, subscription, log_time = struct.unpack_from("<BIQ", frame)
                            self.received[self.advertised[subscription]["topic"]].append((log_time, frame[13:]))
                except ConnectionClosed:  # the run is over
                    pass
        except BaseException as err:  # noqa: BLE001 - reported by the test
            self.error = err


@pytest.mark.slow
def test_a_viewer_of_a_live_run_receives_every_step_as_the_log_holds_it(tmp_path):
    from mcap.reader import make_reader

    policy, expert = policy_files(tmp_path, "HalfCheetah-v5")
    port, log = free_port(), tmp_path / "run.mcap"
    viewer = Viewer(port)
    viewer.start()
    # live:=wait: the first step waits for the viewer, so that it sees every step
    summary = summary_of(run_graph("mode:=sensory", "env:=HalfCheetah-v5", f"policy:={policy}", f"expert:={expert}",
                                   "attack:=random", "eps:=0.1", "episodes:=2", "horizon:=30", "baseline:=false",
                                   "live:=wait", f"live_port:={port}", f"record:={log}", "render:=true",
                                   "render_every:=10", "render_size:=64x48"))
    viewer.join(timeout=30)
    assert not viewer.is_alive() and viewer.error is None, viewer.error
    advertised = {channel["topic"]: channel for channel in viewer.advertised.values()}
    assert advertised["/observation"]["schemaName"] == "sensor_msgs/msg/JointState"
    assert advertised["/observation"]["encoding"] == "cdr" and advertised[LIVE_CHANNEL]["encoding"] == "json"

    with open(log, "rb") as f:
        logged = defaultdict(list)
        for _, channel, message in make_reader(f).iter_messages():
            logged[channel.topic].append((message.log_time, message.data))
    assert summary["steps"] == 60
    for channel in STEP_CHANNELS:
        if channel in logged:  # the run's step topics (a run without a timing attack has no /attack/timing)
            assert viewer.received[channel] == logged[channel], channel
    assert len(viewer.received["/observation"]) == 60
    assert viewer.received[CAMERA_CHANNEL] == logged[CAMERA_CHANNEL] and len(logged[CAMERA_CHANNEL]) == 6

    figures = [json.loads(payload) for _, payload in viewer.received[LIVE_CHANNEL]]
    assert [(f["episode"], f["step"]) for f in figures] == [(e, s) for e in range(2) for s in range(30)]
    last = [f for f in figures if f["step"] == 29]
    assert [round(f["return"], 3) for f in last] == summary["returns"]
    assert np.allclose([sum(f["reward"] for f in figures if f["episode"] == e) for e in range(2)], summary["returns"],
                       atol=1e-3)
    assert max(np.abs(f["perturbation"]).max() for f in figures) <= 0.1 + 1e-9


def test_a_live_setting_that_is_none_is_refused():
    out = run_graph("mode:=clean", "live:=maybe")
    assert out.returncode == 1 and "live:= is one of off, on, wait, got 'maybe'" in out.stderr


def test_the_shipped_layout_reads_only_what_a_run_serves_or_logs():
    """Every panel of docs/foxglove/aril-layout.json names a channel of the live view or the log, and a field its
    messages have: a renamed topic or field would leave a panel empty without a word."""
    import re

    from aril_ros import protocol as P
    from aril_ros.runlog.layout import VALUES
    from aril_ros.runlog.live import LIVE_SCHEMA
    from tests.conftest import ROOT

    layout = json.loads((ROOT / "docs" / "foxglove" / "aril-layout.json").read_text())
    fields = {channel: {VALUES[topic]} for channel, topic in STEP_CHANNELS.items() if topic in VALUES}
    fields[LIVE_CHANNEL] = set(LIVE_SCHEMA["properties"])
    paths = [path["value"] for config in layout["configById"].values() for path in config.get("paths", [])]
    paths += [config["topicPath"] for config in layout["configById"].values() if "topicPath" in config]
    assert len(paths) >= 10
    for path in paths:
        topic, _, field = path.partition(".")
        assert topic in fields, path
        assert not field or re.match(r"\w+", field)[0] in fields[topic], path
    images = [config["imageMode"]["imageTopic"] for config in layout["configById"].values() if "imageMode" in config]
    assert images == [CAMERA_CHANNEL] and P.CAMERA_TYPE.endswith("CompressedImage")
    panels = set(re.findall(r'"(\w+![\w-]+)"', json.dumps(layout["layout"])))
    assert panels == set(layout["configById"])  # every configured panel is placed, and only those


def test_a_viewer_that_shows_only_the_camera_counts_as_watching():
    """A viewer subscribes only to what its panels show: one with only the image panel must start a live:=wait run."""
    from websockets.sync.client import connect

    from aril_ros import protocol as P
    from aril_ros.runlog.live import LiveView

    live = LiveView("127.0.0.1", 0, P.STEP_TOPICS, camera=True)
    try:
        assert not live.watched()
        with connect(live.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
            advertised = {}
            while not advertised:
                message = json.loads(ws.recv())
                if message["op"] == "advertise":
                    advertised = {channel["topic"]: channel["id"] for channel in message["channels"]}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": advertised["/sim/camera/image/compressed"]}]}))
            deadline = time.monotonic() + 10
            while not live.watched() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert live.watched()
    finally:
        live.close()
