"""What ``qchain run`` checks before it builds a model: output paths (the plots' folder, the
recording, ``--rrd``) and the Rerun viewer named by ``--connect``."""

from __future__ import annotations

import os
from pathlib import Path

from .cli_errors import BadInput

#: s a Rerun viewer named by ``--connect`` has to answer the connection (its HTTP/2 settings).
CONNECT_TIMEOUT = 5.0
#: Bytes of the scene file's name that name a default recording (``runs/<stem>-<time>.mcap``).
MAX_STEM_BYTES = 100

# --------------------------------------------------------------------------------------
# paths and viewers, checked before the run


def _shown(path) -> str:
    """A path as text that any terminal shows (bytes that are not UTF-8 escaped)."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _recording_stem(scene_path) -> str:
    """The name a scene's default recording starts with: its file's stem as printable
    UTF-8 (other bytes become ``_``), at most :data:`MAX_STEM_BYTES` bytes."""
    stem = Path(scene_path).stem if scene_path else "run"
    text = os.fsencode(stem).decode("utf-8", "replace")
    text = "".join(c if c.isprintable() and c not in "\ufffd/\\" else "_" for c in text)
    text = text.encode("utf-8")[:MAX_STEM_BYTES].decode("utf-8", "ignore")
    return text if text.strip(". ") else "run"


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) the file system of ``folder`` (or its nearest existing
    parent) takes."""
    for p in [folder, *folder.parents]:
        try:
            if p.exists():
                return int(os.pathconf(p, "PC_NAME_MAX"))
        except (OSError, ValueError):
            break
    return 255


def check_output_path(flag: str, path, extra: str = "") -> None:
    """Refuse an output file path the run could not use, before the run: a NUL character,
    a name that is not UTF-8 text (a recording stores its path and Rerun takes UTF-8), a
    file name longer than the file system takes (with ``extra``, the suffix of a file
    written beside it, e.g. ``.journal``).

    Raises
    ------
    BadInput
        naming ``flag``, the path and what is wrong.
    """
    if path is None:
        return
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if "\0" in text:
        shown = text.replace("\0", "\\0")
        raise BadInput(f"{flag} path {shown} contains a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise BadInput(f"{flag} path {_shown(text)} is not UTF-8 text; choose a name of UTF-8 characters") from None
    p = Path(text)
    limit = _name_max(p.parent if str(p.parent) else Path("."))
    size = len(os.fsencode(p.name))
    if size + len(extra.encode()) > limit:
        name = _shown(p.name)
        name = name if len(name) <= 40 else name[:37] + "..."
        beside = f" and its {extra} file beside it needs {len(extra.encode())} more" if extra else ""
        raise BadInput(f"{flag} file name {name} is {size} bytes long{beside}: a file name may have at most {limit} "
                       "bytes there")


def check_output_folder(what: str, folder) -> Path:
    """Make sure ``folder`` can take a command's outputs before anything runs: no NUL
    character, no file where a folder must be, made if missing, writable; returns it.

    Raises
    ------
    BadInput
        naming ``what`` (e.g. ``"the results folder"``), the folder and what is wrong.
    """
    import tempfile

    text = os.fspath(folder)
    if "\0" in text:
        shown = text.replace("\0", "\\0")
        raise BadInput(f"{what} {shown} contains a NUL character")
    p = Path(text)
    for parent in [p, *p.parents]:
        if parent.exists() and not parent.is_dir():
            raise BadInput(f"{what} {_shown(p)} cannot be made: {_shown(parent)} is a file")
    try:
        p.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=p) as fh:
            fh.write(b"qchain")
    except OSError as err:
        raise BadInput(f"{what} {_shown(p)} cannot be written: {err.strerror or err}") from None
    return p


def viewer_silence(url: str, timeout: float = CONNECT_TIMEOUT) -> str | None:
    """None when a Rerun viewer answers at ``url`` within ``timeout`` s, else why not, in
    words (:func:`qchain.recording.rerun_sink.probe_viewer`, which the recording and
    ``qchain replay`` use too). The Rerun SDK waits for a peer that accepts and never
    answers without end, so ``qchain run --connect`` asks first."""
    from .recording.rerun_sink import probe_viewer  # (loads no Rerun: the command starts at once)

    return probe_viewer(url, timeout)
