"""Run logging: the public face of qchain's recording service (:mod:`qchain.recording`).

The simulation hands :class:`RunLogger` one :class:`StepRecord` a step (``log()``), or many
at once as columns (``log_columns()``) or as rows of float64 numbers (``log_rows()``, see
:class:`RecordLayout`); :class:`qchain.recorder.ChainRecorder` does the latter for
:func:`qchain.simulate`. The simulating process only appends its records to the run's
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
:func:`recover` makes a killed run's recording whole. :func:`replay` re-logs a recording
into Rerun; :func:`foxglove_layout` is the Foxglove layout qchain ships. Reading a file from
anywhere is bounded in time and memory (:class:`ReadLimits`); every bad file is a
:class:`RecordingFormatError` naming it and the byte where it is bad.

Command line: :func:`add_logging_arguments` adds ``--mcap OUT``, ``--serve``, ``--connect
URL``, ``--rrd OUT``, ``--bind``, ``--rerun-rate`` and ``--realtime``;
:func:`logger_from_args` builds the logger; :func:`check_outputs` refuses bad output paths
before a run starts. Without flags a run records to ``runs/<scene-stem>-<timestamp>.mcap``.

This module knows no dynamics: it never imports the simulation.
"""

from __future__ import annotations

import argparse
import os

from .recording.bounded import ReadLimits
from .recording.foxglove_layout import foxglove_layout, layout_json
from .recording.journal import journal_path
from .recording.logger import DEFAULT_MAX_QUEUE, RunLogger
from .recording.options import add_logging_arguments, check_outputs, default_mcap_path
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
from .recording.replay import ReplaySession, layout_main, recover, recover_main, replay, replay_main
from .recording.rerun_sink import DEFAULT_BIND
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
    "replay_main",
    "recover",
    "recover_main",
    "layout_main",
    "foxglove_layout",
    "layout_json",
    "add_logging_arguments",
    "logger_from_args",
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

_default_mcap_path = default_mcap_path  # reachable where a parameter has the same name


def logger_from_args(args: argparse.Namespace, info: RunInfo, default_mcap_path: str | os.PathLike | None = None,
                     **kwargs) -> RunLogger:
    """Build the :class:`RunLogger` the flags of :func:`add_logging_arguments` ask for.

    Parameters
    ----------
    args : argparse.Namespace
    info : RunInfo
    default_mcap_path : path or None
        The recording path when ``--mcap`` is not given; ``None`` takes
        :func:`default_mcap_path` of ``info.scene_path``.
    **kwargs
        Passed on to :class:`RunLogger`. With ``--serve`` the logger lingers (keeps the
        viewer served after the run until Ctrl-C) unless ``linger=False`` is passed.

    Raises
    ------
    ValueError
        ``--serve`` together with ``--connect``.
    LoggingError
        An output path that cannot be used (see :func:`check_outputs`).
    """
    serve = bool(getattr(args, "serve", False))
    connect = getattr(args, "connect", None)
    if serve and connect:
        raise ValueError("--serve and --connect exclude each other")
    path = getattr(args, "mcap", None)
    if path is None:
        path = default_mcap_path if default_mcap_path is not None else _default_mcap_path(info.scene_path)
    kwargs.setdefault("linger", serve)
    kwargs.setdefault("rerun_rate", getattr(args, "rerun_rate", None))
    return RunLogger(info, path, serve=serve, connect=connect, rrd=getattr(args, "rrd", None),
                     bind=getattr(args, "bind", DEFAULT_BIND), **kwargs)
