"""Precompiled CDR decoders for the UCMS samples a station takes in steady state.

Why: cyclonedds's Python IDL machinery decodes a sample field by field through generic
"machines" (an alignment, a ``struct.unpack_from`` and a method call per scalar, a dict of
members per struct), about 28 us for one ``C_Monitored_Characteristic``; a station
following 1,000 robots takes some 11,000 of them a second (docs/benchmarks.md). This is
the mirror of :mod:`blackbox.transport.cdr_encoder`: the layout of a type is worked out
once, from cyclonedds's own machines for that type (the same alignment rules for XCDR1 and
XCDR2), into one generated Python function per type and version: the fixed runs of fields
become a single precompiled ``struct.Struct`` each, sequences of fixed-size elements one
``unpack_from`` for all their elements, and only strings and sequence counts are looked at
as they come.

Same answers as ``datatype.deserialize(payload)``, by construction: a compiled decoder
returns only where every byte it read was there and well formed; anything unusual (a
truncated or foreign payload, an empty string without its terminator, bad UTF-8,
big-endian data, a header naming another encoding) is handed to cyclonedds's own
``deserialize``, which then decodes it or raises exactly as before. Tests compare both on
random samples of every supported type, in both XCDR versions, and on truncated and
garbage payloads.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

from cyclonedds.idl import _machinery as m

from blackbox.errors import BlackBoxError
from blackbox.transport.cdr_layout import CodeGen, UnsupportedMachine, resolve, struct_machine

Decoder = Callable[[bytes], Any]


@dataclass
class _Gen(CodeGen):
    """Decoder state: a fixed run becomes one ``unpack_from`` into the variables in
    ``targets``."""

    targets: list[str] = field(default_factory=list)

    def variable(self) -> str:
        self.counter += 1
        return f"_x{self.counter}"

    def flush(self) -> None:
        """Close the current fixed run: one ``unpack_from`` for all its fields and pads."""
        if not self.fmt:
            return
        unpacker = self.name("_S", struct.Struct("<" + self.fmt))
        if self.targets:
            self.emit(f"{', '.join(self.targets)}, = {unpacker}.unpack_from(data, pos)")
        else:  # only padding: still checked to be there, as the next read needs it
            self.emit(f"{unpacker}.unpack_from(data, pos)")
        self.emit(f"pos += {unpacker}.size")
        self.fmt, self.targets = "", []

    def pad_at_run_time(self, alignment: int) -> str:
        return f"pos += (4 - pos) % {alignment}"

    def fixed(self, code: str, size: int, alignment: int) -> str:
        self.align(alignment)
        self.fmt += code
        target = self.variable()
        self.targets.append(target)
        self.k = (self.k + size) % self.mod
        return target


@dataclass(frozen=True, slots=True)
class _Scalar:
    """The element of cyclonedds's XCDR2 sequence-of-primitive machine (which keeps only
    the element's struct code, alignment and size)."""

    code: str
    alignment: int
    size: int


def _element_layout(machine: Any, align_max: int) -> tuple[str, Any, int] | None:
    """For a sequence element that is a scalar, or a struct of scalars with no padding
    inside (so every element has the same layout and follows the previous one with no
    gap): its struct format, its type (``None`` for a scalar) and its alignment; else
    ``None``."""
    if isinstance(machine, m.InstanceMachine):
        machine = resolve(machine)
    if type(machine) in (m.PrimitiveMachine, _Scalar):
        return str(machine.code), None, min(int(machine.alignment), align_max)
    if type(machine) is not m.StructMachine:
        return None
    fmt, size, alignment = "", 0, 1
    for sub in machine.members_machines.values():
        if type(sub) is not m.PrimitiveMachine:
            return None
        a = min(int(sub.alignment), align_max)
        if size % a:
            return None
        fmt += sub.code
        size += int(sub.size)
        alignment = max(alignment, a)
    if size % alignment:
        return None
    return fmt, machine.type, alignment


def _member(gen: _Gen, machine: Any) -> str:
    """Code reading one member; returns the expression of its value."""
    if isinstance(machine, m.InstanceMachine):
        machine = resolve(machine)
    if type(machine) is m.PrimitiveMachine:
        return gen.fixed(machine.code, machine.size, machine.alignment)
    if type(machine) is m.EnumMachine:
        raw = gen.fixed("I", 4, 4)
        enum: Any = machine.enum  # the IdlEnum class (cyclonedds types it as a member)
        members = gen.name("_E", {int(e.value): e for e in enum})
        return f"{members}.get({raw}, {raw})"
    if type(machine) is m.StructMachine:
        datatype = gen.name("_T", machine.type)
        parts = [_member(gen, sub) for sub in machine.members_machines.values()]
        return f"{datatype}({', '.join(parts)})"
    if type(machine) is m.StringMachine and machine.bound is None:
        return _string(gen)
    if type(machine) is m.SequenceMachine and machine.maxlen is None:
        return _sequence(gen, machine.submachine, bool(machine.add_size_header))
    if type(machine) is m.PlainCdrV2SequenceOfPrimitiveMachine and machine.max_length is None:
        scalar = _Scalar(machine.code, int(machine.alignment), int(machine.size))
        return _sequence(gen, scalar, False)
    raise UnsupportedMachine(type(machine).__name__)


def _string(gen: _Gen) -> str:
    gen.align(4)
    gen.flush()
    length, end, value = gen.variable(), gen.variable(), gen.variable()
    gen.emit(f"{length}, = _LEN.unpack_from(data, pos)")
    gen.emit(f"{end} = pos + 3 + {length}")  # the text ends before the terminating 0
    gen.emit(f"if {length} == 0 or {end} >= len(data): raise _Unusual")
    gen.emit(f"{value} = data[pos + 4:{end}].decode()")
    gen.emit(f"pos = {end} + 1")
    gen.unknown()
    return value


def _sequence(gen: _Gen, element: Any, add_size_header: bool) -> str:
    gen.align(4)
    gen.flush()
    value = gen.variable()
    dheader = None
    if add_size_header:
        size, dheader = gen.variable(), gen.variable()
        gen.emit(f"{size}, = _LEN.unpack_from(data, pos)")
        gen.emit("pos += 4")
        gen.emit(f"{dheader} = pos + {size}")
    count = gen.variable()
    gen.emit(f"{count}, = _LEN.unpack_from(data, pos)")
    gen.emit("pos += 4")
    layout = _element_layout(element, gen.align_max)
    if layout is None:
        _each_element(gen, element, count, value)
    else:
        _all_elements(gen, layout, count, value)
    if dheader is not None:
        gen.emit(f"pos = {dheader}")
    gen.unknown()
    return value


def _all_elements(gen: _Gen, layout: tuple[str, Any, int], count: str, value: str) -> None:
    """Elements of one fixed layout: one ``unpack_from`` for all of them."""
    fmt, datatype, alignment = layout
    size = struct.calcsize("<" + fmt)
    if alignment > 4:  # after the count the offset is 4-aligned only: pad before the first
        gen.emit(f"if {count}: pos += (4 - pos) % {alignment}")
    gen.emit(f"if pos + {size} * {count} > len(data): raise _Unusual")
    flat = gen.variable()
    gen.emit(f"{flat} = _unpack_many({fmt!r}, {count}, data, pos)")
    gen.emit(f"pos += {size} * {count}")
    if datatype is None:
        gen.emit(f"{value} = list({flat})")
        return
    width = len(fmt)
    make = gen.name("_T", datatype)
    args = ", ".join(f"{flat}[_i + {j}]" for j in range(width))
    gen.emit(f"{value} = [{make}({args}) for _i in range(0, {width} * {count}, {width})]")


def _each_element(gen: _Gen, element: Any, count: str, value: str) -> None:
    """Elements of run-time length (strings, structs holding them): one after the other,
    every alignment worked out at run time (where an element starts varies)."""
    gen.emit(f"{value} = []")
    gen.emit(f"for _ in range({count}):")
    outer = gen.indent
    gen.indent += "    "
    gen.unknown()
    item = _member(gen, element)
    gen.flush()
    gen.emit(f"{value}.append({item})")
    gen.indent = outer


class _Unusual(BlackBoxError):
    """The payload is not a plain little-endian sample: cyclonedds decides (an internal
    signal: it never leaves this module)."""


@lru_cache(maxsize=512)
def _elements(fmt: str, count: int) -> struct.Struct:
    """The struct of ``count`` elements of format ``fmt`` (sequences are short and their
    lengths repeat)."""
    return struct.Struct("<" + fmt * count)


def _unpack_many(fmt: str, count: int, data: bytes, pos: int) -> tuple[Any, ...]:
    return _elements(fmt, count).unpack_from(data, pos)


def compile_decoder(datatype: type, use_version_2: bool) -> Decoder:
    """A function decoding the little-endian ``payload`` (with its 4-byte header) of a
    ``datatype`` sample in the given XCDR version, raising on anything else; or
    :class:`UnsupportedMachine`."""
    machine = struct_machine(datatype, use_version_2)
    gen = _Gen(align_max=4 if use_version_2 else 8)
    gen.emit("pos = 4")
    result = _member(gen, machine)
    gen.flush()
    gen.emit(f"return {result}")
    source = "def decode(data):\n" + "\n".join(gen.lines) + "\n"
    namespace: dict[str, Any] = {"_LEN": struct.Struct("<I"), "_Unusual": _Unusual,
                                 "_unpack_many": _unpack_many, **gen.names}
    exec(compile(source, f"<cdr decoder of {datatype.__name__}>", "exec"), namespace)
    decode: Decoder = namespace["decode"]
    decode.__doc__ = source  # the generated code, for whoever debugs it
    return decode


def _version_of_header(flags: int) -> bool | None:
    """What cyclonedds makes of the header's second byte (read as a signed byte): ``True``
    for its XCDR2 machine, ``False`` for XCDR1, ``None`` for big-endian data (left to
    cyclonedds)."""
    signed = flags - 256 if flags > 127 else flags
    if not signed & 1:
        return None
    return signed > 3


def sample_decoder(datatype: type) -> Callable[[bytes], Any]:
    """``datatype.deserialize`` with compiled decoders for both XCDR versions: the same
    sample, or the same exception, for every payload; ``datatype.deserialize`` itself
    where the type has no compiled decoder."""
    fallback: Callable[[bytes], Any] = datatype.deserialize  # type: ignore[attr-defined]
    try:
        v1, v2 = compile_decoder(datatype, False), compile_decoder(datatype, True)
    except UnsupportedMachine:
        return fallback
    by_flags: list[Decoder | None] = []
    for flags in range(256):
        version = _version_of_header(flags)
        by_flags.append(None if version is None else (v2 if version else v1))

    def decode(payload: bytes) -> Any:
        compiled = by_flags[payload[1]] if len(payload) >= 4 else None
        if compiled is not None:
            try:
                return compiled(payload)
            except Exception:  # unusual or malformed: cyclonedds decides, as before
                pass
        return fallback(payload)

    return decode


_CACHE: dict[type, Callable[[bytes], Any]] = {}


def decoder_for(datatype: type) -> Callable[[bytes], Any]:
    """The decoder of ``datatype`` (see :func:`sample_decoder`), built on first use."""
    if datatype not in _CACHE:
        _CACHE[datatype] = sample_decoder(datatype)
    return _CACHE[datatype]


__all__ = ["Decoder", "compile_decoder", "decoder_for", "sample_decoder"]
