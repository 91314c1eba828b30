"""What ``qchain run`` checks before it builds a model: the values of its numeric flags
(:data:`FLAG_RANGES`), output paths (the plots' folder, the recording, ``--rrd``), the
address ``--serve`` binds and the Rerun viewer named by ``--connect``."""

from __future__ import annotations

import argparse

import errno
import math
import os
import sys
from pathlib import Path
from urllib.parse import urlsplit

from ..checks.addresses import host_ok as _host_ok
from ..checks.text import show_path
from ..checks.paths import file_in_the_way, file_kind, has_nul, show_nul
from .errors import BadInput

#: s a Rerun viewer named by ``--connect`` has to answer the connection (its HTTP/2 settings).
CONNECT_TIMEOUT = 5.0
#: Bytes of the scene file's name that name a default recording (``runs/<stem>-<time>.mcap``).
MAX_STEM_BYTES = 100
#: URL schemes ``--connect`` takes (those :func:`qchain.recording.rerun_sink.probe_viewer` knows).
VIEWER_SCHEMES = ("rerun+http", "rerun+https", "rerun", "http", "https")


def flag_ranges() -> dict:
    """``{argparse dest: (flag, Range)}``: the numeric flags of ``qchain run`` and their ranges
    (:mod:`qchain.checks.bounds`), declared once."""
    from ..checks.bounds import DURATION, SAMPLE_RATE, Range

    return {
        "duration": ("--duration", DURATION),
        "rerun_rate": ("--rerun-rate", SAMPLE_RATE),
        "viewer_timeout": ("--viewer-timeout", Range(0.0, 3600.0, "s", low_open=True)),
    }


def check_flag_values(args, ranges: dict | None = None) -> None:
    """Refuse a numeric flag outside its range, NaN and infinities too (:class:`BadInput`
    naming the flag, the bound and the value)."""
    for dest, (flag, rng) in (flag_ranges() if ranges is None else ranges).items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        if not (isinstance(value, (int, float)) and math.isfinite(value) and rng.contains(value)):
            raise BadInput(f"argument {flag}: expected {rng.what()}, found {rng.shown(value)}")


def check_viewer_url(flag: str, url) -> None:
    """Refuse a viewer URL that cannot name one: a scheme of :data:`VIEWER_SCHEMES`, a host (an
    IP address or a DNS name) and a port from 1 to 65535 (:class:`BadInput` naming ``flag``)."""
    if url is None:
        return
    text = str(url)
    shown = text if len(text) <= 80 else text[:77] + "..."
    example = "rerun+http://127.0.0.1:9876/proxy"
    if not text.strip():
        raise BadInput(f"{flag}: expected a Rerun viewer's URL such as {example}, found an empty string")
    if any(c.isspace() or not c.isprintable() for c in text):
        raise BadInput(f"{flag}: expected a URL without spaces or control characters, found {shown!r}")
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError as err:
        raise BadInput(f"{flag}: expected a URL with a port from 1 to 65535, found {shown!r} ({err})") from None
    if parts.scheme not in VIEWER_SCHEMES:
        raise BadInput(f"{flag}: expected a URL of scheme {', '.join(VIEWER_SCHEMES)} (such as {example}), found "
                       f"{shown!r}")
    if not parts.hostname or not _host_ok(parts.hostname):
        raise BadInput(f"{flag}: expected a URL naming a host (an IP address or a DNS name), found {shown!r}")
    if port is not None and not 1 <= port <= 65535:
        raise BadInput(f"{flag}: expected a URL with a port from 1 to 65535, found {shown!r}")


def check_bind_address(flag: str, host) -> None:
    """Refuse an address to listen on that is neither an IPv4 address nor a host name with one
    (:class:`BadInput` naming ``flag``)."""
    if host is None:
        return
    shown = str(host) if len(str(host)) <= 80 else str(host)[:77] + "..."
    if not _host_ok(str(host)):
        raise BadInput(f"{flag}: expected an IPv4 address (127.0.0.1, 0.0.0.0) or a host name, found {shown!r}")
    from ..recording.rerun_sink import listen_address
    from ..recording.records import LoggingError

    try:
        listen_address(str(host))
    except LoggingError as exc:
        raise BadInput(f"{flag}: {str(exc).removeprefix('bind: ')}") from None

# --------------------------------------------------------------------------------------
# paths and viewers, checked before the run


def _fs_encodable(c: str) -> bool:
    """Whether the file system's encoding (ASCII in a C locale without UTF-8 mode) takes ``c``."""
    try:
        c.encode(sys.getfilesystemencoding())
        return True
    except UnicodeEncodeError:
        return False


def _recording_stem(scene_path) -> str:
    """The name a scene's default recording starts with: its file's stem as printable
    UTF-8 (other bytes become ``_``), at most :data:`MAX_STEM_BYTES` bytes."""
    stem = Path(scene_path).stem if scene_path else "run"
    text = os.fsencode(stem).decode("utf-8", "replace")
    text = "".join(c if c.isprintable() and c not in "\ufffd/\\" and _fs_encodable(c) else "_" for c in text)
    text = text.encode("utf-8")[:MAX_STEM_BYTES].decode("utf-8", "ignore")
    return text if text.strip(". ") else "run"


def check_output_path(flag: str, path, extra: str = "") -> None:
    """Refuse an output file path the run could not use: a NUL character, a name that is not
    UTF-8, a file name longer than the file system takes (with ``extra``, the suffix of a file
    written beside it), a path that is not a regular file (:class:`BadInput` naming ``flag``)."""
    if path is None:
        return
    text = os.fsdecode(path)
    if has_nul(text):
        raise BadInput(f"{flag} path {show_nul(text)} contains a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise BadInput(f"{flag} path {show_path(text)} is not UTF-8 text; choose a name of UTF-8 characters") from None
    from ..recording.options import fs_limits  # (the recording's libraries load when a path is checked)

    p = Path(text)
    limit = fs_limits(Path(os.path.abspath(p)).parent)[0]
    size = len(os.fsencode(p.name))
    if size + len(extra.encode()) > limit:
        name = show_path(p.name)
        name = name if len(name) <= 40 else name[:37] + "..."
        beside = f" and its {extra} file beside it needs {len(extra.encode())} more" if extra else ""
        raise BadInput(f"{flag} file name {name} is {size} bytes long{beside}: a file name may have at most {limit} "
                       "bytes there")
    for target in [p] + ([Path(text + extra)] if extra else []):
        _existing_output_problem(flag, target)


def _existing_output_problem(flag: str, p: Path) -> None:
    """Refuse an output file path that exists as something other than a regular file (a
    folder, a device such as /dev/null or /dev/full, a FIFO), or is a loop of symbolic links
    (the recording's own checks, :func:`qchain.logging.check_outputs`, say the rest)."""
    import stat

    shown = show_path(p)
    shown = shown if len(shown) <= 120 else shown[:117] + "..."
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return
    except OSError as err:
        if err.errno != errno.ELOOP:  # a file where a folder must be, a path too long: the recording's checks say it
            return
        raise BadInput(f"{flag} path {shown} cannot be used: {err.strerror or err}") from None
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return
    kind = file_kind(mode, other="not a file")
    raise BadInput(f"{flag} path {shown} is {kind}: expected a regular file (or a path where one can be made)")


def check_output_folder(what: str, folder) -> Path:
    """Make ``folder`` ready for a command's outputs (no NUL, no file in the way, made,
    writable) and return it; :class:`BadInput` naming ``what`` otherwise."""
    import tempfile

    text = os.fspath(folder)
    if has_nul(text):
        raise BadInput(f"{what} {show_nul(text)} contains a NUL character")
    p = Path(text)
    blocker = file_in_the_way(p)
    if blocker is not None:
        raise BadInput(f"{what} {show_path(p)} cannot be made: {show_path(blocker)} is a file")
    try:
        p.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=p) as fh:
            fh.write(b"qchain")
    except OSError as err:
        raise BadInput(f"{what} {show_path(p)} cannot be written: {err.strerror or err}") from None
    return p


def viewer_silence(url: str, timeout: float = CONNECT_TIMEOUT) -> str | None:
    """None when a Rerun viewer answers at ``url`` within ``timeout`` s, else why not
    (:func:`qchain.recording.rerun_sink.probe_viewer`)."""
    from ..recording.rerun_sink import probe_viewer  # (loads no Rerun: the command starts at once)

    return probe_viewer(url, timeout)


def path_argument(text: str) -> Path:
    """A path argument, not empty (``Path("")`` would be the working folder)."""
    if not text:
        raise argparse.ArgumentTypeError("expected a path, found an empty string")
    return Path(text)


def file_argument(text: str) -> Path:
    """An output file's path argument: :func:`path_argument`, not ending in ``/``."""
    if text.endswith(os.sep) or (os.altsep and text.endswith(os.altsep)):
        raise argparse.ArgumentTypeError(f"expected a file's path, found {text!r}, which ends in {os.sep!r} (a "
                                         "folder's name)")
    return path_argument(text)
