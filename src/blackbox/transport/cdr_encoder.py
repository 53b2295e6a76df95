"""Precompiled CDR encoders for the UCMS samples the black box writes in steady state.

Why: cyclonedds's Python IDL machinery serialises a sample field by field through generic
"machines" (a method call, an alignment and a ``struct.pack_into`` per scalar), about 34 us
for one ``C_Monitored_Characteristic`` (docs/benchmarks.md), and the black box writes some
twenty a second. The layout of a type never changes, so here it is worked out once, from
cyclonedds's own machines for that type (the same alignment rules, XCDR1 or XCDR2, the
same byte order), into one generated Python function per type: the fixed runs of fields
become a single precompiled ``struct.Struct`` each, alignment is resolved at compile time
wherever the offset is known, and only sequences and strings are walked at run time.

A type whose machines use anything not handled here (unions, optionals, appendable or
mutable structs, arrays, bounded sequences) gets no encoder and keeps cyclonedds's own
serialisation; tests compare both byte for byte and read the result with a cyclonedds reader.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

from cyclonedds.idl import _machinery as m

from blackbox.transport.cdr_layout import CodeGen, UnsupportedMachine, resolve, struct_machine

Encoder = Callable[[Any], bytes]


def _enum_value(value: Any) -> int:
    return value if type(value) is int else int(value.value)


@dataclass
class _Gen(CodeGen):
    """Encoder state: a fixed run becomes one ``pack`` of the expressions in ``args``."""

    args: list[str] = field(default_factory=list)

    def flush(self) -> None:
        """Close the current fixed run: one ``pack`` for all its fields and pads."""
        if not self.fmt:
            return
        packer = self.name("_S", struct.Struct("<" + self.fmt))
        self.emit(f"out += {packer}.pack({', '.join(self.args)})")
        self.fmt, self.args = "", []

    def pad_at_run_time(self, alignment: int) -> str:
        return f"out += _ZERO[:(4 - len(out)) % {alignment}]"

    def fixed(self, code: str, size: int, alignment: int, expr: str) -> None:
        self.align(alignment)
        self.fmt += code
        self.args.append(expr)
        self.k = (self.k + size) % self.mod


def _fixed_size(machine: Any, align_max: int) -> int | None:
    """The encoded size of an element that is the same for every value (with no inner
    padding that depends on where it starts), else ``None``."""
    if isinstance(machine, m.PrimitiveMachine):
        return int(machine.size)
    if isinstance(machine, m.EnumMachine):
        return 4
    if isinstance(machine, m.InstanceMachine):
        machine = resolve(machine)
    if isinstance(machine, m.StructMachine):
        total = 0
        for sub in machine.members_machines.values():
            size = _fixed_size(sub, align_max)
            if size is None:
                return None
            sub_align = min(_alignment(sub), align_max)
            if total % sub_align:
                return None
            total += size
        return total
    return None


def _alignment(machine: Any) -> int:
    if isinstance(machine, m.InstanceMachine):
        machine = resolve(machine)
    if isinstance(machine, m.StructMachine):
        return max((_alignment(s) for s in machine.members_machines.values()), default=1)
    return int(getattr(machine, "alignment", 1))


def _member(gen: _Gen, machine: Any, expr: str, depth: int) -> None:
    if isinstance(machine, m.InstanceMachine):
        machine = resolve(machine)
    if isinstance(machine, m.PrimitiveMachine):
        gen.fixed(machine.code, machine.size, machine.alignment, expr)
    elif isinstance(machine, m.EnumMachine):
        gen.fixed("I", 4, 4, f"_enum({expr})")
    elif type(machine) is m.StructMachine:
        for name, sub in machine.members_machines.items():
            _member(gen, sub, f"{expr}.{name}", depth)
    elif type(machine) is m.StringMachine and machine.bound is None:
        gen.align(4)
        gen.flush()
        raw = f"_b{depth}"
        gen.emit(f"{raw} = {expr}.encode()")
        gen.emit(f"out += _LEN.pack(len({raw}) + 1)")
        gen.emit(f"out += {raw}")
        gen.emit("out += b'\\x00'")
        gen.unknown()
    elif type(machine) is m.SequenceMachine and machine.maxlen is None:
        _sequence(gen, machine, expr, depth)
    else:
        raise UnsupportedMachine(type(machine).__name__)


def _sequence(gen: _Gen, machine: Any, expr: str, depth: int) -> None:
    gen.align(4)
    gen.flush()
    items = f"_v{depth}"
    gen.emit(f"{items} = {expr}")
    if machine.add_size_header:
        header = f"_h{depth}"
        gen.emit(f"{header} = len(out)")
        gen.emit("out += _LEN.pack(0)")
    gen.emit(f"out += _LEN.pack(len({items}))")
    element = machine.submachine
    size = _fixed_size(element, gen.align_max)
    after = 1
    if size is not None:
        after = 4
        while after > 1 and size % after:
            after //= 2
    # each element starts where the count left the offset, or where the previous one ended
    inner_mod = min(4, after)
    gen.emit(f"for _e{depth} in {items}:")
    outer_indent = gen.indent
    gen.indent += "    "
    gen.k, gen.mod = 0, inner_mod
    _member(gen, element, f"_e{depth}", depth + 1)
    gen.flush()
    gen.indent = outer_indent
    if machine.add_size_header:
        gen.emit(f"_LEN.pack_into(out, {header}, len(out) - {header} - 4)")
    gen.unknown(inner_mod)


def compile_encoder(datatype: type, use_version_2: bool) -> Encoder:
    """An encoder producing exactly ``sample.serialize(use_version_2=...)`` for samples of
    ``datatype`` (little-endian), or :class:`UnsupportedMachine`."""
    machine = struct_machine(datatype, use_version_2)
    idl = datatype.__idl__  # type: ignore[attr-defined]
    head = idl.xcdrv2_head if use_version_2 else idl.xcdrv1_head
    gen = _Gen(align_max=4 if use_version_2 else 8)
    gen.emit(f"out = bytearray({bytes([0, 1 | head, 0, 0])!r})")
    _member(gen, machine, "sample", 0)
    gen.flush()
    gen.emit("return bytes(out)")
    source = "def encode(sample):\n" + "\n".join(gen.lines) + "\n"
    namespace: dict[str, Any] = {"_ZERO": bytes(8), "_LEN": struct.Struct("<I"),
                                 "_enum": _enum_value, **gen.names}
    exec(compile(source, f"<cdr encoder of {datatype.__name__}>", "exec"), namespace)
    encode: Encoder = namespace["encode"]
    encode.__doc__ = source  # the generated code, for whoever debugs it
    return encode


_CACHE: dict[tuple[type, bool], Encoder | None] = {}


def encoder_for(datatype: type, use_version_2: bool) -> Encoder | None:
    """The compiled encoder of ``datatype``, built on first use; ``None`` when the type
    uses something this module does not translate."""
    key = (datatype, use_version_2)
    if key not in _CACHE:
        try:
            _CACHE[key] = compile_encoder(datatype, use_version_2)
        except UnsupportedMachine:
            _CACHE[key] = None
    return _CACHE[key]


def sample_writer(writer: Any) -> Callable[[Any], None]:
    """``writer.write`` with the compiled encoder: the same bytes handed to Cyclone through
    the same call cyclonedds's ``DataWriter.write`` makes, or ``writer.write`` itself where
    the type has no encoder or this cyclonedds does not look as expected."""
    try:
        from cyclonedds._clayer import ddspy_write
        from cyclonedds.core import DDSException

        datatype = writer.data_type
        use_version_2 = writer._use_version_2
        ref = writer._ref
    except (ImportError, AttributeError):
        return cast(Callable[[Any], None], writer.write)
    if use_version_2 is None:  # the type's own default, as serialize() decides
        use_version_2 = datatype.__idl__.default_version == 2
    encode = encoder_for(datatype, bool(use_version_2))
    if encode is None:
        return cast(Callable[[Any], None], writer.write)

    def write(sample: Any) -> None:
        if type(sample) is not datatype:
            raise TypeError(f"{sample} is not of type {datatype}")
        data = encode(sample)
        if len(data) % 4:
            data += bytes(4 - len(data) % 4)
        ret = ddspy_write(ref, data)
        if ret < 0:
            raise DDSException(ret, f"Occurred while writing sample in {writer!r}")

    return write
