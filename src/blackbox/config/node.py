"""YAML configuration nodes that remember where they came from.

Every value read from a configuration file is a :class:`ConfigNode` carrying its file,
line, column and key path (``setup[1].topics[0].filter.window_size``), so any error
anywhere in the loading code names exactly one place in the user's file.
"""

from __future__ import annotations

import builtins
import difflib
import math
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from blackbox.errors import BlackBoxError


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


def _scalar_value(node: yaml.Node) -> Any:
    if node.tag == _STR_TAG:
        return node.value
    return yaml.SafeLoader("").construct_object(node, deep=True)


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
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ConfigError("file not found", str(p)) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot read file: {exc}", str(p)) from None
        return cls.parse(text, str(p))

    @classmethod
    def parse(cls, text: str, file: str = "<config>") -> ConfigNode:
        try:
            root = yaml.compose(text, Loader=yaml.SafeLoader)
            if root is None:
                return cls(_SCALAR, None, file, 1, 1, "")
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
            return (self._value,)
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
