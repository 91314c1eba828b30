"""Output paths (checked before a run starts) and the command-line flags of recording."""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shutil
import tempfile
from pathlib import Path

from .journal import journal_owner, journal_path
from .records import LoggingError
from .rerun_sink import DEFAULT_BIND
from .scan import MAGIC

__all__ = ["check_outputs", "default_mcap_path", "add_logging_arguments", "MIN_FREE_BYTES"]

#: Free bytes an output's folder must have before a run starts (a recording takes about
#: 0.1 MB a simulated second at 50 samples a second, its journal as much again).
MIN_FREE_BYTES = 16 << 20


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(mcap: str | os.PathLike | None, rrd: str | os.PathLike | None = None,
                  scene_path: str | os.PathLike | None = None, min_free: int = MIN_FREE_BYTES) -> list[str]:
    """Check the output paths of a run before it starts; create their folders.

    Refused with :class:`~qchain.logging.LoggingError` naming the path and why: a folder;
    the scene file itself; the same path for the MCAP and the ``.rrd``; a folder that
    cannot be created or written, or has less than ``min_free`` bytes free; a recording
    another run is writing (its journal is locked); a killed run's journal not recovered
    yet; an existing file that is not an MCAP recording. Returns notices (an earlier
    recording that will be replaced).
    """
    notices: list[str] = []
    outs = [(name, Path(p)) for name, p in (("mcap", mcap), ("rrd", rrd)) if p is not None]
    if len(outs) == 2 and os.path.abspath(outs[0][1]) == os.path.abspath(outs[1][1]):
        raise LoggingError(f"--mcap and --rrd are the same path {outs[0][1]}: each output needs its own file")
    for name, p in outs:
        if p.is_dir():
            raise LoggingError(f"{name} must be a file path, got the folder {p}")
        if scene_path is not None and (_same(p, Path(scene_path)) or
                                       os.path.abspath(p) == os.path.abspath(scene_path)):
            raise LoggingError(f"{name} path {p} is the scene file itself: it would be overwritten; choose another "
                               "path")
        parent = p.parent if str(p.parent) else Path(".")
        try:
            parent.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=parent, prefix=".qchain-write-test-"):
                pass
        except OSError as exc:
            raise LoggingError(f"cannot write {name} file {p}: {exc.strerror or exc} ({parent})") from None
        free = shutil.disk_usage(parent).free
        if free < min_free:
            raise LoggingError(f"cannot write {name} file {p}: only {free / 1e6:.1f} MB free in {parent} (a run "
                               f"needs at least {min_free / 1e6:.0f} MB)")
        if name == "mcap":
            j = journal_path(p)
            owner = journal_owner(j)
            if owner is not None:
                who = f" (pid {owner})" if owner else ""
                raise LoggingError(f"another run{who} is writing {p}: choose another path")
            if j.exists():
                raise LoggingError(f"{j} holds the records of a run that was killed while writing {p}: "
                                   f"`qchain recover {p}` makes that recording whole (or remove the journal)")
            if p.exists() and p.stat().st_size > 0:
                with open(p, "rb") as fh:
                    head = fh.read(len(MAGIC))
                if head != MAGIC:
                    raise LoggingError(f"{p} exists and is not an MCAP recording; refusing to overwrite it")
                notices.append(f"replacing the earlier recording {p}")
        elif p.exists() and p.stat().st_size > 0:
            notices.append(f"replacing the earlier .rrd file {p}")
    return notices


def default_mcap_path(scene_path: str | os.PathLike | None = None, runs_dir: str | os.PathLike = "runs",
                      now: _dt.datetime | None = None) -> Path:
    """``runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap`` (local time), made unique with a suffix
    (also against a journal of a run still writing there).

    Parameters
    ----------
    scene_path : path or None
        The scene file; its stem names the recording (``run`` without one).
    runs_dir : path
        Folder of the recordings, relative to the working directory by default.
    now : datetime or None
        The time stamp (default: now).
    """
    stem = Path(scene_path).stem if scene_path else "run"
    stamp = (now or _dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    base = Path(runs_dir) / f"{stem}-{stamp}"
    path = base.with_suffix(".mcap")
    k = 1
    while path.exists() or journal_path(path).exists():
        path = Path(f"{base}-{k}.mcap")
        k += 1
    return path


def add_logging_arguments(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """Add ``--mcap OUT``, ``--serve``, ``--connect URL``, ``--rrd OUT``, ``--bind HOST``,
    ``--rerun-rate HZ`` and ``--realtime`` to ``parser`` (one argument group, returned)."""
    g = parser.add_argument_group(
        "recording and viewing",
        "Every run is recorded to an MCAP file (default runs/<scene>-<timestamp>.mcap); replay it with "
        "`qchain replay FILE`, or open it in Foxglove (layout: `qchain layout FILE`).",
    )
    g.add_argument("--mcap", metavar="OUT", type=Path, default=None,
                   help="MCAP recording path (default: runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap)")
    g.add_argument("--serve", action="store_true", help="serve a live Rerun web viewer on 127.0.0.1 and print its URL")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    g.add_argument("--rrd", metavar="OUT", type=Path, default=None, help="also write a Rerun .rrd file")
    g.add_argument("--bind", default=DEFAULT_BIND, help="address --serve listens on (default 127.0.0.1: this machine "
                   "only)")
    g.add_argument("--rerun-rate", metavar="HZ", type=float, default=None,
                   help="send the viewer/.rrd at most HZ samples a simulated second (default: all; the MCAP always "
                        "gets all)")
    g.add_argument("--realtime", action="store_true",
                   help="pace the run to the wall clock (1 simulated second a second), to watch it live")
    return g
