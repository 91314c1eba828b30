"""Run logging: the public face of qchain's recording service (:mod:`qchain.recording`).

The simulation hands :class:`RunLogger` one :class:`StepRecord` a step (``log()``), or many
at once as columns (``log_columns()``) or as rows of float64 numbers (``log_rows()``, see
:class:`RecordLayout`); :class:`qchain.recording.recorder.ChainRecorder` does the latter for
:func:`qchain.sim.simulation`. The simulating process only appends its records to the run's
journal (one write a batch, on disk at once); a writer process reads the journal and writes
the MCAP recording and the Rerun view, so killing every process of a run loses at most a
batch (``flush_interval``, 0.25 s of simulation time by default).

The recording (``.mcap``, the mcap library's ``Writer``): one JSON state channel with every
field of every record (``/qchain/state``), and the official Foxglove messages (protobuf,
``foxglove-sdk``): the frame tree world -> base -> segment tips (``/qchain/tf``), the
backbone as line strips (``/qchain/arm``) and as a point cloud
(``/qchain/backbone_points``). Metadata carry the scene, the model parameters and the
qchain version under a CRC32 seal. :func:`read_recording` and :func:`read_mcap` read it back
bit for bit; a damaged chunk loses only its own records (``Recording.gaps`` says which);
:func:`recover` makes a killed run's recording whole; :func:`export_ros2` writes a recording as a
ROS 2 bag (:mod:`qchain.recording.ros2`). :func:`replay` re-logs a recording
into Rerun; :func:`foxglove_layout` is the Foxglove layout qchain ships. Reading a file from
anywhere is bounded in time and memory (:class:`ReadLimits`); every bad file is a
:class:`RecordingFormatError` naming it and the byte where it is bad.

:func:`check_outputs` refuses bad output paths before a run starts; the command-line flags
that ask for a recording (``--mcap OUT``, ``--serve``, ``--connect URL``, ``--rrd OUT``,
``--bind``, ``--rerun-rate``, ``--realtime``) are :mod:`qchain.cli.recording`'s. Without flags a run records to ``runs/<scene-stem>-<timestamp>.mcap``.

This module knows no dynamics: it never imports the simulation.
"""

from __future__ import annotations

from .recording.bounded import ReadLimits
from .recording.foxglove_layout import foxglove_layout, layout_json
from .recording.journal import journal_path
from .recording.logger import DEFAULT_MAX_QUEUE, RunLogger
from .recording.options import check_outputs, default_mcap_path
from .recording.reader import Gap, Recording, read_mcap, read_recording
from .recording.records import (
    DEFAULT_FLUSH_INTERVAL,
    DEFAULT_FLUSH_WALL_INTERVAL,
    FORMAT_VERSION,
    SEGMENT_COLORS,
    TOPICS,
    LoggingError,
    LoggingWarning,
    RecordingFormatError,
    RecordLayout,
    RunInfo,
    StepRecord,
)
from .recording.replay import ReplaySession, recover, replay
from .recording.ros2 import ROS2_TOPICS, export_ros2
from .recording.writer import prepare_writer

__all__ = [
    "StepRecord",
    "RecordLayout",
    "RunInfo",
    "RunLogger",
    "LoggingError",
    "RecordingFormatError",
    "LoggingWarning",
    "Recording",
    "Gap",
    "read_recording",
    "read_mcap",
    "ReadLimits",
    "replay",
    "ReplaySession",
    "recover",
    "export_ros2",
    "ROS2_TOPICS",
    "foxglove_layout",
    "layout_json",
    "check_outputs",
    "default_mcap_path",
    "journal_path",
    "prepare_writer",
    "TOPICS",
    "SEGMENT_COLORS",
    "FORMAT_VERSION",
    "DEFAULT_FLUSH_INTERVAL",
    "DEFAULT_FLUSH_WALL_INTERVAL",
    "DEFAULT_MAX_QUEUE",
]
