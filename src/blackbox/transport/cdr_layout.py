"""What the compiled CDR encoder and decoder share: generating one Python function per
type from cyclonedds's own machines, with the offset tracked at compile time.

Both walk a type's fields in order and group the fixed runs (scalars and their padding)
into one precompiled ``struct.Struct`` each; where the offset is known well enough, padding
is decided at compile time, otherwise at run time. :class:`CodeGen` holds that state; the
encoder (:mod:`~blackbox.transport.cdr_encoder`) and the decoder
(:mod:`~blackbox.transport.cdr_decoder`) say what a fixed run turns into (one ``pack``,
one ``unpack_from``) and how padding is done at run time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from cyclonedds.idl import _machinery as m

from blackbox.errors import BlackBoxError


class UnsupportedMachine(BlackBoxError):
    """A machine the compilers do not translate (the type keeps cyclonedds's own code)."""


@dataclass
class CodeGen:
    """Code generation state: the lines, the names the code refers to (precompiled structs
    and types), the current fixed run's format, and what is known about the offset
    (relative to the payload after the 4-byte encapsulation header): it is ``k`` modulo
    ``mod``."""

    align_max: int
    lines: list[str] = field(default_factory=list)
    names: dict[str, Any] = field(default_factory=dict)
    fmt: str = ""
    k: int = 0
    mod: int = 8
    indent: str = "    "
    counter: int = 0

    def name(self, prefix: str, value: Any) -> str:
        self.counter += 1
        key = f"{prefix}{self.counter}"
        self.names[key] = value
        return key

    def emit(self, line: str) -> None:
        self.lines.append(self.indent + line)

    def flush(self) -> None:
        """Close the current fixed run (the encoder packs it, the decoder unpacks it)."""
        raise NotImplementedError

    def pad_at_run_time(self, alignment: int) -> str:
        """The line that aligns to ``alignment`` where the offset is known only then."""
        raise NotImplementedError

    def align(self, alignment: int) -> None:
        a = min(alignment, self.align_max)
        if a <= 1:
            return
        if a <= self.mod:
            pad = (-self.k) % a
            self.fmt += "x" * pad
            self.k = (self.k + pad) % self.mod
            return
        self.flush()  # the offset is not known well enough: align at run time
        self.emit(self.pad_at_run_time(a))
        self.k, self.mod = 0, a

    def unknown(self, mod: int = 1) -> None:
        """After something of run-time length: the offset is known modulo ``mod`` only."""
        self.k, self.mod = 0, mod


def resolve(machine: Any) -> Any:
    """The struct machine an instance machine stands for, in its XCDR version."""
    idl = machine.type.__idl__
    if idl.v1_machine is None:
        idl.populate()
    return idl.v2_machine if machine.use_version_2 else idl.v1_machine


def struct_machine(datatype: type, use_version_2: bool) -> Any:
    """The top-level machine of ``datatype`` in the given XCDR version, which must be a
    plain struct's; else :class:`UnsupportedMachine`."""
    idl = datatype.__idl__  # type: ignore[attr-defined]
    if idl.v1_machine is None:
        idl.populate()
    machine = idl.v2_machine if use_version_2 else idl.v1_machine
    if type(machine) is not m.StructMachine:
        raise UnsupportedMachine(type(machine).__name__)
    return machine


__all__ = ["CodeGen", "UnsupportedMachine", "resolve", "struct_machine"]
