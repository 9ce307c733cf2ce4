"""Run logs: ROS 2 bags in MCAP, written step by step, read back into arrays, recovered when cut short.

Rooms: :mod:`~aril_ros.runlog.layout` (what a log holds: channels, schemas, metadata records),
:mod:`~aril_ros.runlog.cdr` (the fields the recorder reads from raw messages), :mod:`~aril_ros.runlog.stream`
(the chunk-per-step MCAP writer), :mod:`~aril_ros.runlog.writer`, :mod:`~aril_ros.runlog.recorder` (a graph run's
steps joined, written in order, and each episode's figures taken once), :mod:`~aril_ros.runlog.rules` (what every
reader checks a step against), :mod:`~aril_ros.runlog.reader` and :mod:`~aril_ros.runlog.recovery`. The DAgger
data set of run logs is :func:`aril_ros.dataset.load_dagger_dataset`. No rclpy and no torch here.
"""
from .layout import RunLogError
from .reader import RunLog, read_run
from .recorder import StepFault, StepRecorder
from .recovery import Recovery, recover
from .writer import RunLogWriter

__all__ = ["RunLog", "RunLogError", "RunLogWriter", "Recovery", "StepFault", "StepRecorder", "read_run", "recover"]
