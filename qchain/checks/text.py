"""Text from outside (file names, recorded messages) shown to a person on one line.

Standard library only: the command line's error path imports it before numpy loads.
"""

from __future__ import annotations

__all__ = ["printable"]

_CONTROL = {c: f"\\x{c:02x}" for c in [*range(0x20), 0x7F, *range(0x80, 0xA0)] if c != 0x09}
_CONTROL.update({0x0A: "\\n", 0x0D: "\\r"})


def printable(text: str) -> str:
    """``text`` as one line any terminal shows as it is: control characters (a newline, an
    escape sequence from a file's name or its outcome message) and bytes that are not
    UTF-8 (a file name's, kept as surrogates) escaped."""
    text = str(text).translate(_CONTROL)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        text = "".join(f"\\x{ord(ch) - 0xDC00:02x}" if 0xDC80 <= ord(ch) <= 0xDCFF
                       else ch.encode("utf-8", "backslashreplace").decode("ascii") if 0xD800 <= ord(ch) <= 0xDFFF
                       else ch for ch in text)
    return text
