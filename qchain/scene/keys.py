"""The vocabulary of the scene file's declaration: a key (:class:`Field`) and a table of keys
(:class:`KeyTable`). :mod:`qchain.scene.format` declares the format with them, and so do the
modules that declare a table of their own (:mod:`qchain.scene.payload`): they import this
module, not the format, which lists their tables."""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..checks.bounds import Range

__all__ = ["Field", "KeyTable"]

#: how the documentation names each kind of :class:`Field` (a kind not here: its own name)
_TYPE_TEXTS = {"per_segment": "3 numbers a segment", "number_or_per_segment": "number, or 3 a segment",
               "times": "array of numbers, increasing", "rows": "array of pressure vectors",
               "names": "array of strings", "tables": "array of tables", "choice": "string",
               "path": "string (a folder path)",
               "tensions": "array of numbers, one a tendon",
               "number_or_tensions": "number, or one a tendon", "tension_rows": "array of tension arrays"}


@dataclass(frozen=True)
class Field:
    """One key of a scene table.

    Attributes
    ----------
    key : str
    kind : str
        ``number``, ``integer``, ``boolean``, ``string``, ``path``, ``choice``, ``vector``
        (``size`` numbers), ``matrix`` (``size`` arrays of ``size`` numbers), ``per_segment``
        (3 numbers a segment, flat or nested),
        ``number_or_per_segment``, ``times`` (strictly increasing), ``rows`` (per-segment
        vectors, one a time), ``names`` (an array of ``choices``), ``table`` or ``tables``
        (an array of tables).
    doc : str
        What the key means (Markdown).
    range : Range, optional
        Bounds of the number, or of every entry of an array.
    default : str
        The default, as the documentation states it ("" for a required key or none).
    required : bool
    choices : tuple of str
    size : int, optional
        Entries of a ``vector``, rows and columns of a ``matrix``.
    when : tuple of str
        The ``type`` values of its table the key belongs to (empty: all).
    """

    key: str
    kind: str
    doc: str
    range: Range | None = None
    default: str = ""
    required: bool = False
    choices: tuple = ()
    size: int | None = None
    when: tuple = ()

    def type_text(self) -> str:
        if self.kind == "vector":
            return f"array of {self.size} numbers"
        if self.kind == "matrix":
            return f"{self.size} arrays of {self.size} numbers"
        return _TYPE_TEXTS.get(self.kind, self.kind)

    def range_text(self) -> str:
        if self.choices:
            return ", ".join(f'`"{c}"`' for c in self.choices)
        if self.range is not None and (self.range.low is not None or self.range.high is not None):
            return replace(self.range, unit="").text()  # the bounds alone: the unit has its own column
        return ""


@dataclass(frozen=True)
class KeyTable:
    """A table of a scene file: its dotted ``path`` (``""`` for the top level, ``segments[]``
    for an array of tables), what it is, and its fields."""

    path: str
    doc: str
    fields: tuple[Field, ...]
    required: bool = False

    def __getitem__(self, key: str) -> Field:
        for f in self.fields:
            if f.key == key:
                return f
        raise KeyError(key)

    def keys(self, kind: str | None = None) -> tuple[str, ...]:
        """The keys of the table (those of a ``type`` of it, if ``kind`` is given)."""
        return tuple(f.key for f in self.fields if kind is None or not f.when or kind in f.when)

    def markdown(self, top: str = "Top level") -> list[str]:
        """The table as documentation: a heading (``top`` for the top level), its text and a
        Markdown table of its keys (type, unit, range, default, meaning)."""
        title = top if not self.path else (f"`[[{self.path[:-2]}]]`" if self.path.endswith("[]") else f"`[{self.path}]`")
        out = [f"## {title}", "", self.doc, ""]
        has_when = any(f.when for f in self.fields)
        head = "| key | type | unit | range | default |" + (" with `type` |" if has_when else "") + " meaning |"
        out += [head, "|" + "---|" * (head.count("|") - 1)]
        for f in self.fields:
            unit = f.range.unit if f.range is not None else ""
            default = "**required**" if f.required else (f.default or "none")
            row = f"| `{f.key}` | {f.type_text()} | {_cell(unit)} | {_cell(f.range_text())} | {_cell(default)} |"
            if has_when:
                row += f" {', '.join(f.when) if f.when else 'all'} |"
            out.append(row + f" {_cell(f.doc)} |")
        return out + [""]


def _cell(s: str) -> str:
    return s.replace("|", "\\|")
