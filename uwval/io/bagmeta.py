"""rosbag2's ``metadata.yaml``, read without ruamel.yaml when it is in the usual form.

ruamel.yaml (pure Python) costs ~8 ms to import and ~5 ms to parse the 2-3 kB a bag's
metadata holds: a tenth of a whole ``uwval compare`` of a 15-minute bag. The files rosbag2
(yaml-cpp) and rosbags (ruamel) write use a small part of YAML: block mappings and
sequences, plain scalars, single- and double-quoted strings (yaml-cpp folds the QoS profile
string over several lines with escapes), ``[]``/``{}``. :func:`parse_block_yaml` reads exactly
that part and returns ``None`` on anything else (anchors, tags, comments, block scalars, flow
collections with items, tabs, documents markers, plain scalars that YAML could resolve to a
float, a date or a YAML 1.1 boolean...), and :func:`load_metadata` then asks ruamel. Where it
answers, the answer is ruamel's safe load of the same text (held by the tests on every shared
bag's metadata, the writers' and generated documents).
"""

from __future__ import annotations

import re
from typing import Any

#: Plain scalars taken as they are: no leading indicator, digit, sign or dot (which YAML may
#: resolve to a number, a date, .inf...), no ``: `` or `` #`` inside, no trailing colon.
_PLAIN = re.compile(r"[A-Za-z_/][^\t#]*")
_INT = re.compile(r"-?(?:0|[1-9][0-9]*)")
_NULLS = {"", "~", "null", "Null", "NULL"}
_BOOLS = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
#: plain words that YAML 1.1 (and so some readers) take as booleans: left to ruamel
_AMBIGUOUS = {"y", "Y", "yes", "Yes", "YES", "n", "N", "no", "No", "NO", "on", "On", "ON"}
_AMBIGUOUS |= {"off", "Off", "OFF"}
_ESCAPES = {
    "0": "\0",
    "a": "\a",
    "b": "\b",
    "t": "\t",
    "n": "\n",
    "v": "\v",
    "f": "\f",
    "r": "\r",
    "e": "\x1b",
    " ": " ",
    '"': '"',
    "/": "/",
    "\\": "\\",
    "N": "\x85",
    "_": "\xa0",
    "L": "\u2028",
    "P": "\u2029",
}


class _DeclineError(Exception):
    """The text is not in the supported form: ruamel reads it."""


def load_metadata(text: str) -> Any:
    """The YAML document ``text`` (a rosbag2 ``metadata.yaml``): the fast reader's result
    when it applies, ruamel.yaml's safe load otherwise (which raises on invalid YAML)."""
    got = parse_block_yaml(text)
    if got is not None:
        return got
    from uwval.io.raw import load_yaml

    return load_yaml(text)


def parse_block_yaml(text: str) -> dict[str, Any] | None:
    """The mapping ``text`` holds, if it is written in the block-style subset described in
    the module docstring; ``None`` for anything else (including invalid YAML)."""
    try:
        lines = _lines(text)
        if not lines:
            return None
        node, end = _node(lines, 0, lines[0][0])
        if end != len(lines) or not isinstance(node, dict):
            return None
        return node
    except (_DeclineError, IndexError):
        return None


def _lines(text: str) -> list[tuple[int, str]]:
    """(indent, text) of the non-blank lines; declines tabs, comments, directives."""
    out = []
    for raw in text.split("\n"):
        line = raw[:-1] if raw.endswith("\r") else raw
        if "\t" in line or "\r" in line:
            raise _DeclineError
        body = line.lstrip(" ")
        if not body:
            out.append((-1, ""))  # blank: matters only inside a double-quoted string
            continue
        if body[0] in "#%" or body.startswith(("---", "...")):
            raise _DeclineError
        out.append((len(line) - len(body), body))  # trailing spaces: see the readers
    while out and out[-1][0] < 0:
        out.pop()
    while out and out[0][0] < 0:
        out.pop(0)
    return out


def _skip_blank(lines: list[tuple[int, str]], i: int) -> int:
    while i < len(lines) and lines[i][0] < 0:
        i += 1
    return i


def _node(lines: list[tuple[int, str]], i: int, indent: int) -> tuple[Any, int]:
    """The block node starting at line ``i`` (indented ``indent``); returns it and the index
    of the first line after it."""
    body = lines[i][1]
    if body.rstrip(" ") == "-" or body.startswith("- "):
        return _sequence(lines, i, indent)
    if _key_split(body) is not None:
        return _mapping(lines, i, indent)
    return _scalar_lines(lines, i, indent - 1)


def _key_split(body: str) -> tuple[str, str] | None:
    """(key, rest) of a ``key: rest`` / ``key:`` line with a plain key; None if not one."""
    if body.rstrip(" ").endswith(":") and ": " not in body.rstrip(" "):
        key, rest = body.rstrip(" ")[:-1], ""
    else:
        at = body.find(": ")
        if at < 0:
            return None
        key, rest = body[:at], body[at + 2 :].strip(" ")
        if rest.startswith('"'):
            rest = body[at + 2 :].lstrip(" ")  # a quoted string keeps its trailing spaces
    if not _PLAIN.fullmatch(key) or ": " in key or key.endswith(":"):
        if key[:1] in "'\"?" or not key:
            raise _DeclineError  # quoted or complex keys: ruamel's business
        return None
    if key in _NULLS or key in _BOOLS or key in _AMBIGUOUS:
        raise _DeclineError  # a key YAML resolves to null or a boolean
    return key, rest


def _mapping(lines: list[tuple[int, str]], i: int, indent: int) -> tuple[dict[str, Any], int]:
    out: dict[str, Any] = {}
    while i < len(lines) and lines[i][0] == indent:
        split = _key_split(lines[i][1])
        if split is None:
            raise _DeclineError
        key, rest = split
        if key in out:
            raise _DeclineError  # a duplicate key: ruamel reports it
        i = _skip_blank(lines, i + 1)
        if rest:
            out[key], i = _inline_value(rest, lines, i, indent)
        elif i < len(lines) and lines[i][0] > indent:
            out[key], i = _node(lines, i, lines[i][0])
        elif i < len(lines) and lines[i][0] == indent and lines[i][1].startswith(("- ", "-")):
            if lines[i][1] != "-" and not lines[i][1].startswith("- "):
                raise _DeclineError
            out[key], i = _sequence(lines, i, indent)  # a sequence at the key's indent
        else:
            out[key] = None
        i = _skip_blank(lines, i)
    if i < len(lines) and lines[i][0] > indent:
        raise _DeclineError
    return out, i


def _sequence(lines: list[tuple[int, str]], i: int, indent: int) -> tuple[list[Any], int]:
    out: list[Any] = []
    while i < len(lines) and lines[i][0] == indent:
        body = lines[i][1]
        if body.rstrip(" ") == "-":
            rest = ""
        elif body.startswith("- "):
            rest = body[2:].lstrip(" ")
            if not rest.startswith('"'):
                rest = rest.rstrip(" ")
        else:
            break
        if not rest:
            i = _skip_blank(lines, i + 1)
            if i < len(lines) and lines[i][0] > indent:
                item, i = _node(lines, i, lines[i][0])
            else:
                item = None
        elif rest.startswith(("- ", "?", "&", "*", "!")) or rest == "-":
            raise _DeclineError
        else:
            # "- key: value": a mapping whose lines start where this item's text starts (the
            # line is read again as that mapping's first line; lines are never revisited)
            col = indent + (len(body) - len(rest))
            if _key_split(rest) is not None:
                lines[i] = (col, rest)
                item, i = _mapping(lines, i, col)
            else:
                item, i = _inline_value(rest, lines, _skip_blank(lines, i + 1), indent)
        out.append(item)
        i = _skip_blank(lines, i)
    return out, i


def _inline_value(rest: str, lines: list[tuple[int, str]], i: int, parent: int) -> tuple[Any, int]:
    """A value that starts on its key's (or dash's) line: ``rest``; continuation lines are
    those after it indented deeper than ``parent``."""
    if rest[0] == '"':
        return _double_quoted(rest, lines, i, parent)
    if rest[0] == "'":
        rest = rest.rstrip(" ")
        if len(rest) < 2 or not rest.endswith("'") or "'" in rest[1:-1].replace("''", ""):
            raise _DeclineError  # multi-line or not closed: ruamel's business
        return rest[1:-1].replace("''", "'"), i
    if rest.rstrip(" ") in ("[]", "{}"):
        rest = rest.rstrip(" ")
        return ([] if rest == "[]" else {}), i
    parts = [rest.rstrip(" ")]
    while i < len(lines) and lines[i][0] > parent:
        parts.append(lines[i][1].rstrip(" "))
        i += 1
    return _plain(" ".join(parts)), _skip_blank(lines, i)


def _scalar_lines(lines: list[tuple[int, str]], i: int, parent: int) -> tuple[Any, int]:
    """A scalar that starts on a line of its own (``key:`` then the value below it)."""
    body = lines[i][1] if lines[i][1].startswith('"') else lines[i][1].rstrip(" ")
    return _inline_value(body, lines, i + 1, parent)


def _plain(s: str) -> Any:
    """A plain scalar's value (YAML 1.2 core schema, as ruamel's safe loader resolves it)."""
    if s in _NULLS:
        return None
    if s in _BOOLS:
        return _BOOLS[s]
    if _INT.fullmatch(s):
        return int(s)
    if s in _AMBIGUOUS or not _PLAIN.fullmatch(s) or ": " in s or s.endswith(":"):
        raise _DeclineError
    return s


def _double_quoted(rest: str, lines: list[tuple[int, str]], i: int, parent: int) -> tuple[str, int]:
    """A double-quoted scalar starting at ``rest`` (its opening quote), perhaps folded over
    the following lines (each indented deeper than ``parent``)."""
    out: list[str] = []
    text = rest[1:]
    while True:
        k = 0
        piece: list[str] = []
        hard = 0  # piece[:hard] came from escapes: kept when the line's end is trimmed
        while k < len(text):
            c = text[k]
            if c == '"':
                if text[k + 1 :].strip(" "):
                    raise _DeclineError  # something after the closing quote
                out.append("".join(piece))
                return "".join(out), _skip_blank(lines, i)
            if c == "\\":
                if k + 1 == len(text):  # an escaped line break: joined without a space
                    out.append("".join(piece))
                    piece = []
                    k += 1
                    break
                e = text[k + 1]
                if e in _ESCAPES:
                    piece.append(_ESCAPES[e])
                    hard = len(piece)
                    k += 2
                    continue
                size = {"x": 2, "u": 4, "U": 8}.get(e)
                if size is None:
                    raise _DeclineError
                code = text[k + 2 : k + 2 + size]
                if len(code) != size or not re.fullmatch(r"[0-9A-Fa-f]+", code):
                    raise _DeclineError
                piece.append(chr(int(code, 16)))
                hard = len(piece)
                k += 2 + size
                continue
            piece.append(c)
            k += 1
        else:
            # the line ended inside the string: a line break folds to a space, unless blank
            # lines follow (each of them a newline); trailing spaces of the line are dropped
            out.append("".join(piece[:hard]) + "".join(piece[hard:]).rstrip(" "))
            blanks = 0
            while i < len(lines) and lines[i][0] < 0:
                blanks += 1
                i += 1
            if i >= len(lines) or lines[i][0] <= parent:
                raise _DeclineError  # not closed where it must be
            out.append("\n" * blanks if blanks else " ")
            text = lines[i][1]
            i += 1
            continue
        # escaped line break: the next line's leading spaces are dropped, nothing added
        if i >= len(lines) or lines[i][0] <= parent:
            raise _DeclineError
        text = lines[i][1]
        i += 1
