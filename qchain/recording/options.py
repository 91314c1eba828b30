"""Output paths (checked before a run starts) and the command-line flags of recording."""

from __future__ import annotations

import datetime as _dt
import os
import shutil
import tempfile
from pathlib import Path

from ..checks.paths import has_nul, show_nul
from ..checks.text import show_path
from .journal import journal_owner, journal_path
from .records import LoggingError
from .scan import MAGIC

__all__ = ["check_outputs", "check_output_name", "default_mcap_path", "MIN_FREE_BYTES",
           "JOURNAL_SUFFIX"]

#: Free bytes an output's folder must have before a run starts (a recording takes about
#: 0.1 MB a simulated second at 50 samples a second, its journal as much again).
MIN_FREE_BYTES = 16 << 20


#: What the journal of a recording adds to its file name (``run.mcap.journal``).
JOURNAL_SUFFIX = ".journal"
#: The first bytes of a Rerun .rrd file (its stream header)
RRD_MAGIC = b"RRF"
#: Bytes of a whole path the system takes where it does not say (Linux's PATH_MAX).
_PATH_MAX = 4096


def fs_limits(folder: Path) -> tuple[int, int]:
    """NAME_MAX and PATH_MAX (bytes) of the file system of ``folder`` or its nearest
    existing parent (255 and 4096 where it does not say)."""
    for p in [folder, *folder.parents]:
        try:
            if os.path.isdir(p):
                return int(os.pathconf(p, "PC_NAME_MAX")), int(os.pathconf(p, "PC_PATH_MAX"))
        except (OSError, ValueError):
            break
    return 255, _PATH_MAX


def check_output_name(what: str, path: str | os.PathLike, suffix: str = "") -> Path:
    """Refuse an output path the system or the recording cannot take, before anything is
    made: a NUL character, a name that is not UTF-8 text (a recording stores its path, and
    Rerun takes UTF-8), a file name (with ``suffix``, the name of a file written beside it
    such as ``.journal``) or a folder name longer than the file system takes, or a path
    longer than it takes in all. Returns the path.

    Raises
    ------
    LoggingError
        naming ``what``, the path and the limit.
    """
    text = os.fsdecode(path)
    if has_nul(text):
        raise LoggingError(f"{what} path {show_path(show_nul(text, '?'), 120)} contains a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise LoggingError(f"{what} path {show_path(text, 120)} is not UTF-8 text (a recording stores its path as UTF-8): "
                           "choose a name of UTF-8 characters") from None
    p = Path(text)
    name_max, path_max = fs_limits(Path(os.path.abspath(p)).parent)
    for part in p.parent.parts:
        size = len(os.fsencode(part))
        if size > name_max:
            raise LoggingError(f"{what} path {show_path(text, 120)}: its folder name {show_path(part, 60)} is {size} bytes long, "
                               f"more than the {name_max} bytes a name may have there")
    size, extra = len(os.fsencode(p.name)), len(suffix.encode())
    if size + extra > name_max:
        beside = f" and its {suffix} file beside it needs {extra} more" if suffix else ""
        raise LoggingError(f"{what} path {show_path(text, 120)}: its file name is {size} bytes long{beside}, more than the "
                           f"{name_max} bytes a file name may have there; choose a shorter name")
    whole = len(os.fsencode(os.path.abspath(p))) + extra
    if whole >= path_max:
        raise LoggingError(f"{what} path {show_path(text, 120)} is {whole} bytes long as an absolute path"
                           f"{' with its ' + suffix + ' suffix' if suffix else ''}, more than the {path_max - 1} bytes "
                           "a path may have; choose a shorter one")
    return p


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def refuse_recording(out: str | os.PathLike, recording: str | os.PathLike, what: str) -> None:
    """Refuse an output path that is the recording ``recording`` or its journal: a
    :class:`LoggingError` ``WHAT (PATH): it would be overwritten``."""
    for p in (Path(recording), journal_path(recording)):
        if os.path.abspath(out) == os.path.abspath(p) or (Path(out).exists() and p.exists()
                                                           and os.path.samefile(out, p)):
            raise LoggingError(f"{what} ({p}): it would be overwritten")


def check_outputs(mcap: str | os.PathLike | None, rrd: str | os.PathLike | None = None,
                  scene_path: str | os.PathLike | None = None, min_free: int = MIN_FREE_BYTES) -> list[str]:
    """Check the output paths of a run before it starts and create their folders; returns notices
    (an earlier recording that will be replaced). Refusals are :class:`~qchain.logging.LoggingError`
    naming the path and why (the list: docs/recording.md, "Output paths are checked")."""
    notices: list[str] = []
    outs = [(name, check_output_name(name, p, JOURNAL_SUFFIX if name == "mcap" else ""))
            for name, p in (("mcap", mcap), ("rrd", rrd)) if p is not None]
    if len(outs) == 2 and os.path.abspath(outs[0][1]) == os.path.abspath(outs[1][1]):
        raise LoggingError(f"--mcap and --rrd are the same path {outs[0][1]}: each output needs its own file")
    for name, p in outs:
        try:
            notices += _check_output(name, p, scene_path, min_free)
        except OSError as exc:  # what the system says of the path, as one line naming it
            raise LoggingError(f"cannot use {name} path {show_path(str(p), 120)}: {exc.strerror or exc}") from None
    return notices


def _check_output(name: str, p: Path, scene_path, min_free: int) -> list[str]:
    if p.name.endswith(JOURNAL_SUFFIX):  # a journal's name: another run's would be taken for it
        raise LoggingError(f"{name} path {p} ends in {JOURNAL_SUFFIX!r}, the name of a recording's journal: choose "
                           "another name")
    if p.is_symlink() and not p.exists() and not Path(os.path.realpath(p)).parent.is_dir():
        raise LoggingError(f"{name} path {p} is a link to {os.readlink(p)}, whose folder does not exist: give the "
                           "file's own path (or make that folder)")
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
        # the journal beside the path, and (a link) the one beside the file it names: a run
        # writes through the link, over that file
        target = Path(os.path.realpath(p)) if p.is_symlink() else p
        for q, j in dict.fromkeys([(p, journal_path(p)), (target, journal_path(target))]):
            owner = journal_owner(j)
            if owner is not None:
                who = f" (pid {owner})" if owner else ""
                raise LoggingError(f"another run{who} is writing {q}: choose another path")
            if os.path.lexists(j):
                raise LoggingError(f"{j} holds the records of a run that was killed while writing {q}: "
                                   f"`qchain recover {q}` makes that recording whole (or remove the journal)")
    magic, kind, earlier = (MAGIC, "an MCAP recording", "recording") if name == "mcap" else \
        (RRD_MAGIC, "a Rerun .rrd file", ".rrd file")
    if p.exists() and p.stat().st_size > 0:
        with open(p, "rb") as fh:
            head = fh.read(len(magic))
        if head != magic:  # a recording, a scene, notes: not the user's to lose to a typo
            raise LoggingError(f"{p} exists and is not {kind}; refusing to overwrite it")
        return [f"replacing the earlier {earlier} {p}"]
    return []


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
