"""Replay a run log: republish its topics paced by their log (sim) time, like ``ros2 bag play``.

    aril replay file:=runs/x.mcap rate:=2.0

Messages go out byte for byte as recorded, with the recorded QoS (reliable, keep all), in the
current ``ROS_DOMAIN_ID``; ``/clock`` is among them, so nodes with ``use_sim_time`` follow along.

:data:`COMMAND` is the ``aril_ros.commands`` entry point ``replay``. ``aril --help`` imports this
module to list it, so rclpy is imported only when a replay runs.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

from aril_ros.args import arg
from aril_ros.cli import Command
from aril_ros.runlog import read_run


@dataclass
class ReplayConfig:
    """Arguments of ``aril replay``."""

    file: str = arg("", "the run log (.mcap) to play")
    rate: float = arg(1.0, "playback speed: 2.0 plays twice as fast as sim time; 0 plays without pauses",
                      low=0.0, high=1000.0)
    wait_for_subscribers: int = arg(0, "wait until each topic has this many subscribers (up to 10 s)", low=0, high=1000)


def replay(cfg: ReplayConfig, log=print) -> int:
    """Publish every message of the log; returns how many were published."""
    import rclpy
    from mcap.reader import make_reader
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CompressedImage, JointState

    from aril_ros_nodes.common import STEP_QOS

    read_run(cfg.file, allow_interrupted=True)  # refuse foreign or cut-short files before publishing
    classes = {"sensor_msgs/msg/JointState": JointState, "rosgraph_msgs/msg/Clock": Clock,
               "sensor_msgs/msg/CompressedImage": CompressedImage}  # camera frames of render:=true
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("replay")
    count = 0
    try:
        with open(cfg.file, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            schemas = summary.schemas
            publishers = {cid: node.create_publisher(classes[schemas[ch.schema_id].name], ch.topic, STEP_QOS)
                          for cid, ch in summary.channels.items()}
            deadline = time.monotonic() + 10
            while cfg.wait_for_subscribers and time.monotonic() < deadline and any(
                    p.get_subscription_count() < cfg.wait_for_subscribers for p in publishers.values()):
                time.sleep(0.05)
            start_wall, start_log = time.monotonic(), None
            for _, channel, message in reader.iter_messages(log_time_order=True):
                start_log = message.log_time if start_log is None else start_log
                if cfg.rate > 0:
                    due = start_wall + (message.log_time - start_log) / 1e9 / cfg.rate
                    time.sleep(max(0.0, due - time.monotonic()))
                publishers[channel.id].publish(message.data)
                count += 1
        log(f"[replay] published {count} messages from {cfg.file}", file=sys.stderr)
        time.sleep(0.5)  # let reliable delivery finish before the publishers go away
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return count


COMMAND = Command(config=ReplayConfig, run=replay,
                  summary="Republish a run log's topics paced by sim time (like ros2 bag play).")
