"""YAML configuration nodes that remember where they came from.

Every value read from a configuration file is a :class:`ConfigNode` carrying its file,
line, column and key path (``setup[1].topics[0].filter.window_size``), so any error
anywhere in the loading code names exactly one place in the user's file.
"""

from __future__ import annotations

import builtins
import difflib
import math
import re
import stat
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from blackbox.errors import BlackBoxError
from blackbox.safetext import hidden_character

MAX_FILE_BYTES = 1024 * 1024
"""The largest configuration (or fault schedule, robot model) file read: checked before
parsing, so a huge or endless file (``/dev/zero``) costs nothing."""
MAX_NODES = 200_000
"""The most values a document may expand to, aliases counted at every use: a
billion-laughs document stops here instead of exhausting memory."""
MAX_ALIASES = 10_000
MAX_DEPTH = 64
"""The deepest nesting of mappings and lists."""
TEXT_WHITESPACE = "\n\t"
"""The only invisible characters a string value may hold (multi-line blocks)."""



class ConfigError(BlackBoxError):
    """A configuration problem at one place of one file."""

    def __init__(self, message: str, file: str = "<config>", line: int = 0, column: int = 0,
                 path: str = "") -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column
        self.path = path

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.column}"
        at = f" at {self.path}" if self.path else ""
        return f"{where}:{at}: {self.message}" if at else f"{where}: {self.message}"


_MAP, _SEQ, _SCALAR = "map", "seq", "scalar"
_STR_TAG = "tag:yaml.org,2002:str"


_FLOAT_WITH_EXPONENT = re.compile(r"^[-+]?(?:[0-9][0-9_]*)?(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")


class BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with limits on nesting and alias uses, and YAML 1.2 numbers.

    YAML 1.1 reads ``1e-300`` and ``1e5`` as strings (it wants a dot and a signed
    exponent); people mean numbers, so they are resolved as floats.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        event: Any = self.peek_event()  # type: ignore[no-untyped-call]
        mark: Any = event.start_mark
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise yaml.composer.ComposerError(
                    None, None, f"more than {MAX_ALIASES:,} alias uses", mark)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nested deeper than {MAX_DEPTH} levels", mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def fetch_flow_collection_start(self, token_class: Any) -> None:
        """The scanner reads ahead of the composer (a flow collection may be a key), so
        flow nesting is bounded here too: 1,000 ``[`` would otherwise cost a second."""
        if self.flow_level >= MAX_DEPTH:
            raise yaml.scanner.ScannerError(None, None, f"nested deeper than {MAX_DEPTH} levels",
                                            self.get_mark())
        super().fetch_flow_collection_start(token_class)


BoundedLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_WITH_EXPONENT,
                                    list("-+0123456789."))

def _scalar_value(node: yaml.Node) -> Any:
    if node.tag == _STR_TAG:
        return node.value
    # A constructor of its own per value: it remembers what it built (a shared one would
    # keep every document alive), and it is cheap, unlike a whole SafeLoader.
    return yaml.constructor.SafeConstructor().construct_object(node, deep=True)


def _check_expansion(root: yaml.Node, file: str) -> None:
    """Refuse a document whose aliases expand it beyond :data:`MAX_NODES` values, or an
    alias inside itself, before a single value is built: sizes are counted per distinct
    node, so a billion laughs costs as little as its text."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def children(node: yaml.Node) -> list[yaml.Node]:
        if isinstance(node, yaml.MappingNode):
            return [n for pair in node.value for n in pair]
        if isinstance(node, yaml.SequenceNode):
            return list(node.value)
        return []

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            mark = node.start_mark
            raise ConfigError("invalid YAML: an alias inside the value it names", file,
                              mark.line + 1, mark.column + 1)
        open_nodes.add(key)
        total = 1 + sum(size(child) for child in children(node))
        open_nodes.discard(key)
        sizes[key] = total
        return total

    node = root
    if size(node) <= MAX_NODES:
        return
    while True:  # name the innermost value that alone expands too far
        bigger = [c for c in children(node) if sizes[id(c)] > MAX_NODES]
        if not bigger:
            break
        node = bigger[0]
    mark = node.start_mark
    raise ConfigError(f"invalid YAML: the document expands to more than {MAX_NODES:,} values "
                      "(aliases are counted at every use)", file, mark.line + 1,
                      mark.column + 1)


def read_bounded(path: Path, limit: int = MAX_FILE_BYTES, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes, else one ``ConfigError``;
    never reads more than ``limit + 1`` bytes, so devices and pipes cannot stall it."""
    try:
        if not stat.S_ISREG(path.stat().st_mode):  # before opening: a FIFO blocks open()
            raise ConfigError(f"not a regular file; a {what} must be one", str(path))
        with path.open("rb") as fh:
            data = fh.read(limit + 1)
    except FileNotFoundError:
        raise ConfigError("file not found", str(path)) from None
    except OSError as exc:
        raise ConfigError(f"cannot read file: {exc.strerror or exc}", str(path)) from None
    if len(data) > limit:
        raise ConfigError(f"larger than {limit:,} bytes; a {what} is smaller", str(path))
    return data


class ConfigNode:
    """One node of a YAML document with its location."""

    __slots__ = ("_children", "_kind", "_value", "column", "file", "key_column", "key_line",
                 "line", "path")

    def __init__(self, kind: str, value: Any, file: str, line: int, column: int, path: str) -> None:
        self._kind = kind
        self._value = value if kind == _SCALAR else None
        self._children: Any = value if kind != _SCALAR else None
        self.file = file
        self.line = line
        self.column = column
        self.path = path
        # Where this node's key stands, for errors about the key itself (unknown keys).
        self.key_line = line
        self.key_column = column

    # ---- construction -------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> ConfigNode:
        p = Path(path)
        data = read_bounded(p, what="configuration file")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(f"cannot read file: not UTF-8 text (byte {exc.start})",
                              str(p)) from None
        return cls.parse(text, str(p))

    @classmethod
    def parse(cls, text: str, file: str = "<config>") -> ConfigNode:
        if len(text) > MAX_FILE_BYTES:
            raise ConfigError(f"larger than {MAX_FILE_BYTES:,} characters; a configuration "
                              "is smaller", file)
        try:
            root = yaml.compose(text, Loader=BoundedLoader)
            if root is None:
                return cls(_SCALAR, None, file, 1, 1, "")
            _check_expansion(root, file)
            return cls._from_yaml(root, file, "")
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            line, col = (mark.line + 1, mark.column + 1) if mark else (0, 0)
            problem = exc.problem or exc.context or "invalid YAML"
            ctx = exc.context_mark
            if mark is not None and ctx is not None and ctx.line != mark.line:
                problem += f" ({exc.context or 'construct'} started at line {ctx.line + 1})"
            raise ConfigError(f"invalid YAML: {problem}", file, line, col) from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"invalid YAML: {exc}", file) from None

    @classmethod
    def _from_yaml(cls, node: yaml.Node, file: str, path: str) -> ConfigNode:
        line, col = node.start_mark.line + 1, node.start_mark.column + 1
        if isinstance(node, yaml.MappingNode):
            children: dict[str, ConfigNode] = {}
            for knode, vnode in node.value:
                key = str(_scalar_value(knode))
                child_path = f"{path}.{key}" if path else key
                if key in children:
                    raise ConfigError(f"duplicate key {key!r}", file, knode.start_mark.line + 1,
                                      knode.start_mark.column + 1, child_path)
                child = cls._from_yaml(vnode, file, child_path)
                child.key_line = knode.start_mark.line + 1
                child.key_column = knode.start_mark.column + 1
                children[key] = child
            return cls(_MAP, children, file, line, col, path)
        if isinstance(node, yaml.SequenceNode):
            items = [cls._from_yaml(v, file, f"{path}[{i}]") for i, v in enumerate(node.value)]
            return cls(_SEQ, items, file, line, col, path)
        value = _scalar_value(node)
        return cls(_SCALAR, value, file, line, col, path)

    @classmethod
    def mapping(cls, children: Mapping[str, ConfigNode], at: ConfigNode) -> ConfigNode:
        """A synthetic mapping located at ``at`` (used when translating tug configurations)."""
        return cls(_MAP, dict(children), at.file, at.line, at.column, at.path)

    @classmethod
    def sequence(cls, items: Iterable[ConfigNode], at: ConfigNode) -> ConfigNode:
        return cls(_SEQ, list(items), at.file, at.line, at.column, at.path)

    @classmethod
    def scalar(cls, value: Any, at: ConfigNode) -> ConfigNode:
        return cls(_SCALAR, value, at.file, at.line, at.column, at.path)

    # ---- errors -------------------------------------------------------------------------

    def error(self, message: str) -> ConfigError:
        return ConfigError(message, self.file, self.line, self.column, self.path)

    # ---- shape ----------------------------------------------------------------------------

    @property
    def is_null(self) -> bool:
        return self._kind == _SCALAR and self._value is None

    @property
    def is_map(self) -> bool:
        return self._kind == _MAP

    @property
    def is_list(self) -> bool:
        return self._kind == _SEQ

    def _need_map(self) -> dict[str, ConfigNode]:
        if self._kind != _MAP:
            raise self.error(f"expected a mapping (key: value), got {self._describe()}")
        children: dict[str, ConfigNode] = self._children
        return children

    def _describe(self) -> str:
        if self._kind == _SEQ:
            return "a list"
        if self._kind == _MAP:
            return "a mapping"
        if self._value is None:
            return "nothing (null)"
        return f"{type(self._value).__name__} {self._value!r}"

    # ---- mappings ------------------------------------------------------------------------

    def __contains__(self, key: str) -> bool:
        return self._kind == _MAP and key in self._children

    def keys(self) -> list[str]:
        return list(self._need_map())

    def items(self) -> Iterator[tuple[str, ConfigNode]]:
        return iter(self._need_map().items())

    def __getitem__(self, key: str) -> ConfigNode:
        children = self._need_map()
        if key not in children:
            raise self.error(f"missing required key {key!r}")
        return children[key]

    def get(self, key: str) -> ConfigNode | None:
        """The child at ``key``; ``None`` when absent or explicitly null."""
        child = self._need_map().get(key)
        return None if child is None or child.is_null else child

    def first(self, *keys: str) -> tuple[str, ConfigNode] | None:
        """The first present, non-null key among ``keys`` (for accepted alternate spellings)."""
        children = self._need_map()
        found = [k for k in keys if k in children and not children[k].is_null]
        if len(found) > 1:
            raise children[found[1]].error(f"{found[0]!r} and {found[1]!r} mean the same; give one")
        return (found[0], children[found[0]]) if found else None

    def check_keys(self, allowed: Iterable[str]) -> None:
        """Reject unknown keys, suggesting the closest allowed spelling."""
        allowed = list(allowed)
        for key, child in self._need_map().items():
            if key not in allowed:
                close = difflib.get_close_matches(key, allowed, n=1)
                hint = (f"; did you mean {close[0]!r}?" if close
                        else f"; allowed: {', '.join(sorted(allowed))}")
                raise ConfigError(f"unknown key {key!r}{hint}", child.file, child.key_line,
                                  child.key_column, child.path)

    # ---- lists ------------------------------------------------------------------------------

    def list(self, allow_single: bool = False) -> list[ConfigNode]:
        if self._kind == _SEQ:
            return list(self._children)
        if self.is_null:
            return []
        if allow_single:
            return [self]
        raise self.error(f"expected a list, got {self._describe()}")

    def str_list(self) -> tuple[str, ...]:
        """A list of strings; a single string is accepted as a one-element list."""
        if self._kind == _SCALAR and isinstance(self._value, str):
            return (self.str(),)
        return tuple(item.str() for item in self.list())

    # ---- scalars ------------------------------------------------------------------------------

    @property
    def raw(self) -> Any:
        if self._kind != _SCALAR:
            raise self.error(f"expected a single value, got {self._describe()}")
        return self._value

    def str(self, choices: Iterable[str] | None = None) -> str:
        v = self.raw
        if not isinstance(v, str) or not v:
            raise self.error(f"expected a non-empty string, got {self._describe()}")
        hidden = hidden_character(v, TEXT_WHITESPACE)
        if hidden is not None:
            raise self.error(f"contains an invisible or text-reordering character ({hidden}); "
                             "names must look like what they are")
        if choices is not None:
            choices = list(choices)
            if v not in choices:
                close = difflib.get_close_matches(v, choices, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise self.error(f"unknown value {v!r}; expected one of {', '.join(choices)}{hint}")
        return v

    def float(self, *, min: float | None = None, max: float | None = None,
              min_exclusive: bool = False) -> float:
        v = self.raw
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.error(f"expected a number, got {self._describe()}")
        f = float(v)
        if math.isnan(f) or math.isinf(f):
            raise self.error(f"expected a finite number, got {v!r}")
        if min is not None and (f < min or (min_exclusive and f == min)):
            raise self.error(f"must be {'>' if min_exclusive else '>='} {min:g}, got {v!r}")
        if max is not None and f > max:
            raise self.error(f"must be <= {max:g}, got {v!r}")
        return f

    def int(self, *, min: int | None = None, max: int | None = None) -> int:
        v = self.raw
        if isinstance(v, bool) or not isinstance(v, int):
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            else:
                raise self.error(f"expected an integer, got {self._describe()}")
        if min is not None and v < min:
            raise self.error(f"must be >= {min}, got {v}")
        if max is not None and v > max:
            raise self.error(f"must be <= {max}, got {v}")
        return int(v)

    def bool(self) -> bool:
        v = self.raw
        if not isinstance(v, bool):
            raise self.error(f"expected true or false, got {self._describe()}")
        return v

    def to_python(self) -> Any:
        if self._kind == _MAP:
            return {k: c.to_python() for k, c in self._children.items()}
        if self._kind == _SEQ:
            return [c.to_python() for c in self._children]
        return self._value

    def __repr__(self) -> builtins.str:
        return f"ConfigNode({self._kind} at {self.file}:{self.line}:{self.column} {self.path!r})"
