"""Description files as YAML: plain data with the line of every key (PyYAML's composer
keeps the marks), and problems as ``FILE:LINE: key.path: what is wrong (what is allowed)``.

Read with the YAML 1.2 core schema and refused node by node where YAML 1.1 would guess
(octal-looking numbers, ``yes``/``no``, tags): a description is plain data.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import yaml  # type: ignore[import-untyped]

from bridge_core.wire.errors import ConfigurationError
from bridge_core.wire.registers import Fault


@dataclass(frozen=True)
class Problem:
    line: int
    path: str
    message: str


class DescriptionError(ConfigurationError):
    """A description file is not valid: the first problem as one line, all in ``problems``."""

    def __init__(self, path: Path, problems: Sequence[Problem]) -> None:
        self.path = path
        self.problems = list(problems)
        first = self.lines()[0]
        more = len(self.problems) - 1
        super().__init__(first + (f" (and {more} more problem(s))" if more else ""))

    def lines(self) -> list[str]:
        return [
            f"{self.path}:{p.line}: {p.path + ': ' if p.path else ''}{p.message}"
            for p in self.problems
        ]


# ---------------------------------------------------------------- YAML with line marks
Loc = tuple[str | int, ...]

# The tags a description may carry (YAML 1.2 core schema); any other tag (``!foo``,
# ``!!python/object``, ``!!binary``, ``!!timestamp``) is refused: a description is data.
STR_TAG = "tag:yaml.org,2002:str"
INT_TAG = "tag:yaml.org,2002:int"
FLOAT_TAG = "tag:yaml.org,2002:float"
BOOL_TAG = "tag:yaml.org,2002:bool"
NULL_TAG = "tag:yaml.org,2002:null"
MAP_TAG = "tag:yaml.org,2002:map"
SEQ_TAG = "tag:yaml.org,2002:seq"
# Nodes one file may expand to (aliases copy what they name): a few nested aliases must
# not make a file of a few lines take all memory ("billion laughs").
MAX_NODES = 200_000
_DECIMAL = re.compile(r"^[-+]?[0-9]+$")
_OCTAL = re.compile(r"^0o[0-7]+$")
_HEX = re.compile(r"^0x[0-9a-fA-F]+$")
_LEADING_ZERO = re.compile(r"^[-+]?0[0-9]+$")
_FLOAT = re.compile(r"^[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?$")
_INF = re.compile(r"^[-+]?\.(inf|Inf|INF)$")
_NAN = re.compile(r"^\.(nan|NaN|NAN)$")


class _Resolver(yaml.resolver.Resolver):  # type: ignore[misc]
    """YAML 1.2 core schema: ``0100`` is not octal (it is refused, see ``_int``), ``1:30``
    is not base 60, ``yes``/``no``/``on``/``off`` are text, ``0x2100`` is hex."""

    yaml_implicit_resolvers: ClassVar[dict[str | None, list[tuple[str, re.Pattern[str]]]]] = {}


for _tag, _pattern, _first in (
    (BOOL_TAG, r"^(?:true|True|TRUE|false|False|FALSE)$", "tTfF"),
    (NULL_TAG, r"^(?:~|null|Null|NULL|)$", ["~", "n", "N", ""]),
    (INT_TAG, r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", "-+0123456789"),
    (
        FLOAT_TAG,
        r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$",
        "-+0123456789.",
    ),
):
    _Resolver.add_implicit_resolver(_tag, re.compile(_pattern), list(_first))


class _Loader(
    yaml.reader.Reader,  # type: ignore[misc]
    yaml.scanner.Scanner,  # type: ignore[misc]
    yaml.parser.Parser,  # type: ignore[misc]
    yaml.composer.Composer,  # type: ignore[misc]
    _Resolver,
):
    """PyYAML's reader, scanner, parser and composer (nodes keep their line) with the
    YAML 1.2 resolver; the nodes are turned into data by ``_Builder``, not by PyYAML."""

    def __init__(self, stream: str) -> None:
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        yaml.composer.Composer.__init__(self)
        _Resolver.__init__(self)


class _Refused(Exception):
    """A node the builder cannot turn into data: its line and what is wrong."""

    def __init__(self, node: yaml.Node, loc: Loc, message: str, line: int | None = None) -> None:
        super().__init__(message)
        line = int(node.start_mark.line) + 1 if line is None else line
        self.problem = Problem(line, format_loc(loc), message)


class _Builder:
    """Plain data (dict, list, str, int, float, bool, None) from composed YAML nodes.

    Written here rather than taken from PyYAML's constructor so that every refusal has
    the node's line and key path: a key that is not text (``? [a, b]``), an alias that
    contains itself, a tag that is not plain data, a key given twice, an integer with a
    leading zero (YAML 1.1 read ``0100`` as octal 64, a user padding addresses means 100:
    neither reading is safe, so the file must say which).
    """

    def __init__(self, root: yaml.Node) -> None:
        self.root = root
        self.nodes = 0

    def build(self, node: yaml.Node, loc: Loc, path: tuple[int, ...] = ()) -> Any:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            # the line of the key whose aliases expand so far, not of the anchor's node
            line = line_of(self.root, loc[:1])
            raise _Refused(node, loc[:1], f"more than {MAX_NODES} values (aliases expanded)", line)
        if id(node) in path:
            raise _Refused(node, loc, "a recursive alias (an anchor used inside itself)")
        if isinstance(node, yaml.ScalarNode):
            return self._scalar(node, loc)
        inner = (*path, id(node))
        if isinstance(node, yaml.SequenceNode):
            if node.tag != SEQ_TAG:
                raise _Refused(node, loc, _tag_text(node.tag))
            return [self.build(item, (*loc, i), inner) for i, item in enumerate(node.value)]
        assert isinstance(node, yaml.MappingNode)
        if node.tag != MAP_TAG:
            raise _Refused(node, loc, _tag_text(node.tag))
        data: dict[str, Any] = {}
        merged: dict[str, Any] = {}
        for key, value in node.value:
            if not isinstance(key, yaml.ScalarNode):
                raise _Refused(key, loc, "a key must be a plain name, not a list or mapping")
            if key.tag not in (STR_TAG, INT_TAG, FLOAT_TAG, BOOL_TAG, NULL_TAG):
                raise _Refused(key, loc, _tag_text(key.tag))
            name = str(key.value)
            if name == "<<" and key.style is None:
                # A merge key: the keys of the mapping(s) it names, unless given here.
                sources = value.value if isinstance(value, yaml.SequenceNode) else [value]
                for source in sources:
                    built = self.build(source, (*loc, name), inner)
                    if not isinstance(built, dict):
                        raise _Refused(source, (*loc, name), "a merge key (<<) takes a mapping")
                    merged = {**built, **merged}
                continue
            if name in data:
                raise _Refused(key, (*loc, name), "key given twice (each key once)")
            data[name] = self.build(value, (*loc, name), inner)
        return {**merged, **data}

    def _scalar(self, node: yaml.ScalarNode, loc: Loc) -> Any:
        text, tag = str(node.value), node.tag
        if tag == STR_TAG:
            return text
        if tag == NULL_TAG and text in ("~", "null", "Null", "NULL", ""):
            return None
        if tag == BOOL_TAG and text.lower() in ("true", "false"):
            return text.lower() == "true"
        if tag == INT_TAG:
            return self._int(node, text, loc)
        if tag == FLOAT_TAG:
            if _INF.match(text):
                return -math.inf if text.startswith("-") else math.inf
            if _NAN.match(text):
                return math.nan
            if _FLOAT.match(text):
                return float(text)
        if tag in (NULL_TAG, BOOL_TAG, FLOAT_TAG):
            raise _Refused(node, loc, f"{text!r} is not a {tag.rsplit(':', 1)[1]}")
        raise _Refused(node, loc, _tag_text(tag))

    def _int(self, node: yaml.ScalarNode, text: str, loc: Loc) -> int:
        if _LEADING_ZERO.match(text):
            digits = text.lstrip("+-").lstrip("0") or "0"
            raise _Refused(
                node,
                loc,
                f"{text}: a leading zero is not read (YAML 1.1 took it as octal); write "
                f"{text[0] if text[0] in '+-' else ''}{digits} for decimal, or 0x... for hex",
            )
        if _DECIMAL.match(text):
            return int(text)
        if _HEX.match(text):
            return int(text[2:], 16)
        if _OCTAL.match(text):
            return int(text[2:], 8)
        raise _Refused(node, loc, f"{text!r} is not an integer (decimal, or 0x... for hex)")


def _tag_text(tag: str) -> str:
    return (
        f"tag {tag.replace('tag:yaml.org,2002:', '!!')} is not allowed "
        "(a description is plain data: text, numbers, true/false, lists, mappings)"
    )


def compose(path: Path, raw: bytes) -> tuple[yaml.Node, dict[str, Any]]:
    """The file's root node (for line numbers) and its data; ``DescriptionError`` (one
    line with the line number) for anything that is not a YAML mapping of plain data."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise DescriptionError(
            path,
            [
                Problem(
                    line,
                    "",
                    f"byte 0x{raw[err.start]:02X} is not UTF-8 text "
                    "(a description is a UTF-8 YAML file, not a binary one)",
                )
            ],
        ) from None
    loader: _Loader | None = None
    try:
        loader = _Loader(text)  # its reader refuses non-printable characters at once
        node = loader.get_single_node()
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        line = mark.line + 1 if mark is not None else 1
        raise DescriptionError(
            path, [Problem(line, "", f"not valid YAML: {err.problem or err.context}")]
        ) from None
    except yaml.reader.ReaderError as err:
        line = text[: err.position].count("\n") + 1
        raise DescriptionError(
            path,
            [
                Problem(
                    line,
                    "",
                    f"character {err.character!r} is not allowed in YAML "
                    "(a description is a text file, not a binary one)",
                )
            ],
        ) from None
    except RecursionError:
        raise DescriptionError(path, [Problem(1, "", "nested too deeply")]) from None
    finally:
        if loader is not None:
            loader.dispose()
    if not isinstance(node, yaml.MappingNode):
        line = node.start_mark.line + 1 if node is not None else 1
        raise DescriptionError(path, [Problem(line, "", "the file must be a mapping of keys")])
    try:
        data = _Builder(node).build(node, ())
    except _Refused as err:
        raise DescriptionError(path, [err.problem]) from None
    except RecursionError:
        raise DescriptionError(path, [Problem(1, "", "nested too deeply")]) from None
    return node, data


def node_at(root: yaml.Node, loc: Loc) -> yaml.Node | None:
    """The node a key path leads to, or None."""
    node = root
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            node = next((v for k, v in node.value if k.value == str(part)), None)
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            node = node.value[part] if 0 <= part < len(node.value) else None
        else:
            return None
        if node is None:
            return None
    return node


def line_of(root: yaml.Node, loc: Loc) -> int:
    """The line of the deepest key (or list item) ``loc`` reaches: a missing key's line is
    its mapping's."""
    node = root
    line = int(root.start_mark.line) + 1
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            pair = next(((k, v) for k, v in node.value if k.value == str(part)), None)
            if pair is None:
                break
            key, node = pair
            line = int(key.start_mark.line) + 1
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            if not 0 <= part < len(node.value):
                break
            node = node.value[part]
            line = int(node.start_mark.line) + 1
        else:
            break
    return line


def format_loc(loc: Loc) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


class Checker:
    """Collects the problems that need several keys, each with its key path."""

    def __init__(self, root: yaml.Node, prefix: Loc) -> None:
        self.root = root
        self.prefix = prefix
        self.problems: list[Problem] = []

    def add(self, loc: Loc, message: str) -> None:
        full = (*self.prefix, *loc)
        self.problems.append(Problem(line_of(self.root, full), format_loc(full), message))

    def faults(self, at: Loc, faults: Iterable[Fault], keys: dict[str, str]) -> None:
        """The rulebook's faults (bridge_core.wire.registers) at the keys their fields are
        written under (``keys``: field -> key where they differ; no field: ``at`` itself)."""
        for fault in faults:
            where = at if fault.field is None else (*at, keys.get(fault.field, fault.field))
            self.add(where, fault.message)
