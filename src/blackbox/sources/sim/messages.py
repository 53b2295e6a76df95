"""ROS 1 messages for simulated topics, built with the rosbags type store.

Decoded values are the very dataclasses rosbags returns when it reads a bag, so observers
cannot tell a simulated ``/signal`` from a recorded one; raw bytes are real ROS 1
serializations, so bags written from a simulation open in ``rosbag info``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

BUILTIN_DEFINITIONS: Mapping[str, str] = {
    # audio_common's message is not in the Noetic store; its definition is one line.
    "audio_common_msgs/AudioData": "uint8[] data\n",
}

_NUMPY_OF: Mapping[str, Any] = {
    "bool": np.uint8, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}

ENCODING_CHANNELS: Mapping[str, int] = {
    "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 2, "yuv422": 2,
}


def store_name(ros1_type: str) -> str:
    """``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image`` (the spelling rosbags keys on)."""
    parts = ros1_type.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return ros1_type


def ros1_name(type_name: str) -> str:
    """``sensor_msgs/msg/Image`` -> ``sensor_msgs/Image`` (the spelling ROS 1 uses)."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    return type_name


def robot_typestore(definitions: Mapping[str, str]) -> Typestore:
    """A fresh ROS 1 Noetic store plus the robot's own message definitions.

    Raises ``ValueError`` naming the type whose definition does not parse.
    """
    store = get_typestore(Stores.ROS1_NOETIC)
    for name, text in {**BUILTIN_DEFINITIONS, **definitions}.items():
        try:
            store.register(get_types_from_msg(text, store_name(name)))
        except Exception as exc:  # rosbags raises several parser exception types
            raise ValueError(f"cannot parse message definition of {name}: {exc}") from None
    return store


def default_message(store: Typestore, type_name: str) -> Any:
    """A message of ``type_name`` with every field zero, empty or default-constructed."""
    _, fields = store.fielddefs[type_name]
    cls = store.types[type_name]
    return cls(**{name: _default_field(store, desc) for name, desc in fields})


def _default_field(store: Typestore, desc: tuple[Any, Any]) -> Any:
    kind, arg = desc
    if kind == Nodetype.BASE:
        base = arg[0]
        if base == "string":
            return ""
        if base == "bool":
            return False
        return 0.0 if base.startswith("float") else 0
    if kind == Nodetype.NAME:
        return default_message(store, arg)
    inner, length = arg
    if inner[0] == Nodetype.BASE and inner[1][0] in _NUMPY_OF:
        return np.zeros(length if kind == Nodetype.ARRAY else 0, dtype=_NUMPY_OF[inner[1][0]])
    if kind == Nodetype.ARRAY:
        return [_default_field(store, inner) for _ in range(length)]
    return []


def has_field(store: Typestore, type_name: str, path: str) -> str | None:
    """The type at a dotted ``path`` of ``type_name``: base type, ``uint8[]`` or message name."""
    current = type_name
    parts = path.split(".")
    for i, part in enumerate(parts):
        fields = dict(store.fielddefs[current][1])
        if part not in fields:
            return None
        kind, arg = fields[part]
        last = i == len(parts) - 1
        if kind == Nodetype.NAME and not last:
            current = str(arg)
        elif kind == Nodetype.NAME:
            return str(arg)
        elif kind == Nodetype.BASE and last:
            return str(arg[0])
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and last and arg[0][0] == Nodetype.BASE:
            return f"{arg[0][1][0]}[]"
        else:
            return None
    return None


def set_path(message: Any, path: str, value: Any) -> None:
    *parents, leaf = path.split(".")
    target = message
    for part in parents:
        target = getattr(target, part)
    setattr(target, leaf, value)


def copy_message(message: Any) -> Any:
    """A deep enough copy: nested messages are copied, numpy payloads are shared."""
    changes = {}
    for f in dataclasses.fields(message):
        v = getattr(message, f.name)
        if dataclasses.is_dataclass(v):
            changes[f.name] = copy_message(v)
    return dataclasses.replace(message, **changes)


@dataclass(frozen=True, slots=True)
class ScalarModel:
    """One numeric field: ``mean`` plus noise, uniform in +-``noise`` or gaussian (std),
    plus ``gain * signal(t)`` for each ``(signal, gain)`` of ``follows`` (the robot's
    motion signals, :mod:`.motion`)."""

    field: str
    mean: float
    noise: float = 0.0
    distribution: str = "uniform"
    follows: tuple[tuple[str, float], ...] = ()
    lag: float = 0.0
    """Seconds the measurement lags the motion (transport and filtering delay)."""


@dataclass(frozen=True, slots=True)
class FieldsModel:
    """Several numeric fields of one message, each a :class:`ScalarModel`; a field may be
    an element of a numeric array (``velocity[2]``), the array sized to its largest index."""

    scalars: tuple[ScalarModel, ...]

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(s.field for s in self.scalars)


@dataclass(frozen=True, slots=True)
class ImageModel:
    """A ``sensor_msgs/Image`` of fixed geometry; the pixels are one shared test frame."""

    width: int
    height: int
    encoding: str = "rgb8"

    @property
    def step(self) -> int:
        return self.width * ENCODING_CHANNELS[self.encoding]

    @property
    def payload(self) -> int:
        return self.step * self.height


@dataclass(frozen=True, slots=True)
class BytesModel:
    """A ``uint8[]`` field of ``size`` bytes (audio chunks, compressed frames)."""

    field: str
    size: int


ValueModel = ScalarModel | FieldsModel | ImageModel | BytesModel
NumericModel = ScalarModel | FieldsModel


def scalars_of(model: ValueModel | None) -> tuple[ScalarModel, ...]:
    """The numeric fields a value model sets (none for images, bytes or no model)."""
    if isinstance(model, ScalarModel):
        return (model,)
    if isinstance(model, FieldsModel):
        return model.scalars
    return ()


def split_index(path: str) -> tuple[str, int | None]:
    """``velocity[2]`` -> ``("velocity", 2)``; ``linear.x`` -> ``("linear.x", None)``."""
    if path.endswith("]") and "[" in path:
        head, _, index = path[:-1].rpartition("[")
        return head, int(index)
    return path, None


class TopicMessages:
    """Builds one topic's messages: size up front, value and bytes only when asked."""

    def __init__(self, store: Typestore, ros1_type: str, model: ValueModel | None,
                 frame_id: str = "") -> None:
        self.store = store
        self.type_name = store_name(ros1_type)
        self.model = model
        self._template = default_message(store, self.type_name)
        self._stamped = has_field(store, self.type_name, "header.stamp") is not None
        if self._stamped:
            self._template.header.frame_id = frame_id
        if isinstance(model, ImageModel):
            self._template.height = model.height
            self._template.width = model.width
            self._template.encoding = model.encoding
            self._template.step = model.step
        empty = len(store.serialize_ros1(self._template, self.type_name))
        extra = 0
        if isinstance(model, ImageModel):
            extra = model.payload
        elif isinstance(model, BytesModel):
            extra = model.size
        self.size = empty + extra
        self._payload: np.ndarray | None = None
        self._time_cls = store.types["builtin_interfaces/msg/Time"]
        # Numeric fields in the model's order: (path, array index or None, integer?);
        # arrays are rebuilt per message, sized to their largest index.
        self._plan: list[tuple[str, int | None, bool]] = []
        self._arrays: dict[str, tuple[int, Any]] = {}
        for scalar in scalars_of(model):
            path, index = split_index(scalar.field)
            base = (has_field(store, self.type_name, path) or "").removesuffix("[]")
            self._plan.append((path, index, "int" in base or base in ("byte", "char")))
            if index is not None:
                length = max(self._arrays.get(path, (0, None))[0], index + 1)
                self._arrays[path] = (length, _NUMPY_OF.get(base, np.float64))
        for path, (length, dtype) in self._arrays.items():
            set_path(self._template, path, np.zeros(length, dtype=dtype))
        if self._arrays:
            self.size = len(store.serialize_ros1(self._template, self.type_name)) + extra

    def payload(self) -> np.ndarray:
        """The shared, read-only pixel or byte payload, made on first use."""
        if self._payload is None:
            model = self.model
            if isinstance(model, ImageModel):
                x = np.arange(model.width, dtype=np.uint32)
                y = np.arange(model.height, dtype=np.uint32)[:, None]
                pattern = ((x + y) % 256).astype(np.uint8)
                channels = ENCODING_CHANNELS[model.encoding]
                frame = np.repeat(pattern[:, :, None], channels, axis=2).reshape(-1)
            else:
                assert isinstance(model, BytesModel)
                frame = np.random.default_rng(model.size).integers(0, 256, model.size, np.uint8)
            frame.flags.writeable = False
            self._payload = frame
        return self._payload

    def message(self, seq: int, time: float, value: tuple[float, ...] | None) -> Any:
        """The message ``seq`` at ``time`` with ``value``: one number per numeric field, in
        the model's order (``None`` for models without numeric fields)."""
        msg = copy_message(self._template)
        if self._stamped:
            sec, nsec = divmod(round(time * 1e9), 1_000_000_000)
            msg.header.seq = seq & 0xFFFFFFFF
            msg.header.stamp = self._time_cls(sec=sec, nanosec=nsec)
        model = self.model
        if value is not None and self._plan:
            arrays = {path: np.zeros(length, dtype=dtype)
                      for path, (length, dtype) in self._arrays.items()}
            for (path, index, integer), x in zip(self._plan, value, strict=True):
                number = round(x) if integer and math.isfinite(x) else x
                if index is None:
                    set_path(msg, path, number)
                else:
                    arrays[path][index] = number
            for path, array in arrays.items():
                set_path(msg, path, array)
        elif isinstance(model, ImageModel):
            msg.data = self.payload()
        elif isinstance(model, BytesModel):
            set_path(msg, model.field, self.payload())
        return msg

    def serialize(self, message: Any) -> bytes:
        return bytes(self.store.serialize_ros1(message, self.type_name))

    def definition(self) -> tuple[str, str]:
        """The ROS 1 ``message_definition`` text and md5sum."""
        return self.store.generate_msgdef(self.type_name, ros_version=1)
