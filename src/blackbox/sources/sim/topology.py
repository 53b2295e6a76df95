"""The simulated robot's nodes and topics, read from YAML (see docs/simulator.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import cast

from rosbags.typesys.store import Typestore

from blackbox.config.node import ConfigNode

from .messages import (
    ENCODING_CHANNELS,
    BytesModel,
    FieldsModel,
    ImageModel,
    ScalarModel,
    ValueModel,
    has_field,
    robot_typestore,
    ros1_name,
    scalars_of,
    split_index,
    store_name,
)
from .motion import ModePlan, MotionSignal, modes_from_config, motion_from_config

THESIS_FILE = Path(__file__).with_name("thesis.yaml")

_NUMERIC = ("bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32",
            "int64", "uint64", "float32", "float64")


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """A process of the robot.

    ``requires`` lists input topics without which the node stops publishing: when any of
    them has been silent for ``requires_timeout`` seconds, its publications are skipped
    until the input comes back. Empty (the default) means the node publishes regardless.
    """

    name: str
    pid: int
    cpu: float = 1.0
    cpu_noise: float = 0.0
    memory: float = 20e6
    memory_noise: float = 0.0
    requires: tuple[str, ...] = ()
    requires_timeout: float = 1.0


@dataclass(frozen=True, slots=True)
class TopicSpec:
    """A topic with exactly one publisher. ``jitter`` is the std dev (s) of each period."""

    name: str
    type: str
    publisher: str
    rate: float
    jitter: float = 0.0
    subscribers: tuple[str, ...] = ()
    value: ValueModel | None = None
    frame_id: str = ""

    @property
    def period(self) -> float:
        return 1.0 / self.rate


@dataclass(frozen=True)
class Topology:
    """A whole simulated robot. Build with :meth:`load`, :meth:`parse` or the constructor."""

    name: str
    nodes: Mapping[str, NodeSpec]
    topics: Mapping[str, TopicSpec]
    interface: str = "eth0"
    definitions: Mapping[str, str] = field(default_factory=dict)
    store: Typestore = field(default=None, compare=False, repr=False)  # type: ignore[assignment]
    motion: Mapping[str, MotionSignal] = field(default_factory=dict)
    modes: ModePlan | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "nodes", MappingProxyType(dict(self.nodes)))
        object.__setattr__(self, "topics", MappingProxyType(dict(self.topics)))
        if cast("Typestore | None", self.store) is None:
            object.__setattr__(self, "store", robot_typestore(self.definitions))
        problem = self._problem()
        if problem:
            raise ValueError(problem)

    def _problem(self) -> str | None:
        for t in self.topics.values():
            for scalar in scalars_of(t.value):
                for signal, _ in scalar.follows:
                    if signal not in self.motion:
                        return f"topic {t.name}: follows unknown motion signal {signal}"
        if self.modes is None:
            for m in self.motion.values():
                if m.modes:
                    return f"motion signal {m.name} scales modes but the robot has no modes"
            if t.publisher not in self.nodes:
                return f"topic {t.name}: unknown publisher node {t.publisher}"
            for s in t.subscribers:
                if s not in self.nodes:
                    return f"topic {t.name}: unknown subscriber node {s}"
            if store_name(t.type) not in self.store.types:
                return f"topic {t.name}: unknown message type {t.type}"
        for n in self.nodes.values():
            for r in n.requires:
                if r not in self.topics or n.name not in self.topics[r].subscribers:
                    return f"node {n.name} requires {r} but does not subscribe to it"
        return None

    def published_by(self, node: str) -> tuple[str, ...]:
        return tuple(t.name for t in self.topics.values() if t.publisher == node)

    # ---- loading ----------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> Topology:
        return cls.from_config(ConfigNode.load(path))

    @classmethod
    def parse(cls, text: str, file: str = "<topology>") -> Topology:
        return cls.from_config(ConfigNode.parse(text, file))

    @classmethod
    def thesis(cls) -> Topology:
        """The three-node robot of the thesis experiments (section 6.2.1)."""
        return cls.load(THESIS_FILE)

    @classmethod
    def from_config(cls, root: ConfigNode) -> Topology:
        root.check_keys(["name", "network", "nodes", "topics", "types", "motion", "modes"])
        motion = motion_from_config(root["motion"]) if root.get("motion") is not None else {}
        modes = modes_from_config(root["modes"], motion) if root.get("modes") else None
        if modes is None:
            for name, signal in motion.items():
                if signal.modes:
                    raise root["motion"][name]["modes"].error(
                        "scales operating modes, but the robot has no 'modes:' section")
        name = root["name"].str() if root.get("name") else "robot"
        interface = "eth0"
        net = root.get("network")
        if net is not None:
            net.check_keys(["interface"])
            interface = net["interface"].str()
        definitions: dict[str, str] = {}
        types = root.get("types")
        if types is not None:
            for tname, text in types.items():
                if tname.count("/") != 1:
                    raise text.error(f"message type {tname!r} must look like package/Type")
                definitions[tname] = text.str()
        try:
            store = robot_typestore(definitions)
        except ValueError as exc:
            raise (types or root).error(str(exc)) from None

        nodes: dict[str, NodeSpec] = {}
        node_items = root["nodes"].list()
        if not node_items:
            raise root["nodes"].error("a robot needs at least one node")
        requires_at: dict[str, ConfigNode] = {}
        for i, item in enumerate(node_items):
            spec, req = _node(item, 1000 + 10 * i)
            if spec.name in nodes:
                raise item["name"].error(f"node {spec.name} is defined twice")
            nodes[spec.name] = spec
            if req is not None:
                requires_at[spec.name] = req

        topics: dict[str, TopicSpec] = {}
        for item in root["topics"].list():
            topic = _topic(item, nodes, store)
            for k, scalar in enumerate(scalars_of(topic.value)):
                for followed, _ in scalar.follows:
                    if followed not in motion:
                        where = item["value"]
                        if isinstance(topic.value, FieldsModel):
                            where = where["fields"].list()[k]
                        raise where["follows"].error(
                            f"unknown motion signal {followed!r}; define it under 'motion:'")
            if topic.name in topics:
                raise item["name"].error(f"topic {topic.name} is defined twice")
            topics[topic.name] = topic

        for node_name, req in requires_at.items():
            for r_item, r in zip(req["topics"].list(allow_single=True),
                                 req["topics"].str_list(), strict=True):
                if r not in topics:
                    raise r_item.error(f"unknown topic {r}")
                if node_name not in topics[r].subscribers:
                    raise r_item.error(f"{node_name} requires {r} but is not one of its "
                                       "subscribers")
        return cls(name, nodes, topics, interface, definitions, store, motion, modes)


def _graph_name(node: ConfigNode) -> str:
    name = node.str()
    if not name.startswith("/") or name.endswith("/") or " " in name:
        raise node.error(f"expected a ROS graph name like /camera, got {name!r}")
    return name


def _node(item: ConfigNode, default_pid: int) -> tuple[NodeSpec, ConfigNode | None]:
    item.check_keys(["name", "pid", "cpu", "cpu_noise", "memory", "memory_noise", "requires"])
    name = _graph_name(item["name"])

    def num(key: str, default: float) -> float:
        child = item.get(key)
        return child.float(min=0.0) if child is not None else default

    pid = item["pid"].int(min=1) if item.get("pid") is not None else default_pid
    req = item.get("requires")
    requires: tuple[str, ...] = ()
    timeout = 1.0
    if req is not None:
        req.check_keys(["topics", "timeout"])
        requires = req["topics"].str_list()
        if req.get("timeout") is not None:
            timeout = req["timeout"].float(min=0.0, min_exclusive=True)
    spec = NodeSpec(name, pid, num("cpu", 1.0), num("cpu_noise", 0.0), num("memory", 20e6),
                    num("memory_noise", 0.0), requires, timeout)
    return spec, req


def _topic(item: ConfigNode, nodes: Mapping[str, NodeSpec], store: Typestore) -> TopicSpec:
    item.check_keys(["name", "type", "publisher", "rate", "jitter", "subscribers", "value",
                     "frame_id"])
    name = _graph_name(item["name"])
    type_node = item["type"]
    ros_type = ros1_name(type_node.str())
    if ros_type.count("/") != 1:
        raise type_node.error(f"message type {ros_type!r} must look like package/Type")
    type_name = store_name(ros_type)
    if type_name not in store.types:
        raise type_node.error(f"unknown message type {ros_type!r}; declare its definition "
                              "under 'types:'")
    pub_node = item["publisher"]
    publisher = pub_node.str()
    if publisher not in nodes:
        raise pub_node.error(f"unknown node {publisher}")
    rate = item["rate"].float(min=0.0, min_exclusive=True)
    jitter = item["jitter"].float(min=0.0) if item.get("jitter") is not None else 0.0
    if jitter >= 0.25 / rate:
        raise item["jitter"].error(f"jitter {jitter:g} s is too large for a {rate:g} Hz topic "
                                   f"(keep it under a quarter period, {0.25 / rate:g} s)")
    subscribers: list[str] = []
    sub_node = item.get("subscribers")
    if sub_node is not None:
        for s_item in sub_node.list(allow_single=True):
            s = s_item.str()
            if s not in nodes:
                raise s_item.error(f"unknown node {s}")
            subscribers.append(s)
    frame_id = ""
    if item.get("frame_id") is not None:
        if has_field(store, type_name, "header.frame_id") is None:
            raise item["frame_id"].error(f"{ros_type} has no header")
        frame_id = item["frame_id"].str()
    value_node = item.get("value")
    value = _value(value_node, store, type_name, ros_type) if value_node is not None else None
    return TopicSpec(name, ros_type, publisher, rate, jitter, tuple(subscribers), value, frame_id)


def _value(node: ConfigNode, store: Typestore, type_name: str, ros_type: str) -> ValueModel:
    if "image" in node:
        node.check_keys(["image"])
        img = node["image"]
        img.check_keys(["width", "height", "encoding"])
        if ros_type != "sensor_msgs/Image":
            raise img.error(f"an image value needs type sensor_msgs/Image, not {ros_type}")
        encoding = img["encoding"].str(ENCODING_CHANNELS) if img.get("encoding") else "rgb8"
        return ImageModel(img["width"].int(min=1), img["height"].int(min=1), encoding)
    if "fields" in node:
        node.check_keys(["fields"])
        scalars: list[ScalarModel] = []
        for item in node["fields"].list():
            scalar = _scalar(item, store, type_name, ros_type)
            if any(s.field == scalar.field for s in scalars):
                raise item["field"].error(f"field {scalar.field} is listed twice")
            scalars.append(scalar)
        if not scalars:
            raise node["fields"].error("list at least one field")
        return FieldsModel(tuple(scalars))
    if "bytes" in node:
        field_node = node.get("field")
        field_name = field_node.str() if field_node is not None else "data"
        node.check_keys(["field", "bytes"])
        if has_field(store, type_name, field_name) not in ("uint8[]", "byte[]", "char[]"):
            raise (field_node or node).error(f"{ros_type} has no uint8[] field {field_name!r}")
        return BytesModel(field_name, node["bytes"].int(min=0))
    return _scalar(node, store, type_name, ros_type)


def _scalar(node: ConfigNode, store: Typestore, type_name: str, ros_type: str) -> ScalarModel:
    field_node = node.get("field")
    field_name = field_node.str() if field_node is not None else "data"
    where = field_node or node
    node.check_keys(["field", "mean", "noise", "distribution", "follows", "lag"])
    try:
        path, index = split_index(field_name)
    except ValueError:
        raise where.error(f"bad array index in {field_name!r} (expected name[0])") from None
    base = has_field(store, type_name, path)
    if index is not None:
        if base is None or not base.endswith("[]") or base[:-2] not in _NUMERIC or index < 0:
            raise where.error(f"{ros_type} has no numeric array field {path!r}")
    elif base not in _NUMERIC:
        raise where.error(f"{ros_type} has no numeric field {field_name!r}")
    noise = node["noise"].float(min=0.0) if node.get("noise") is not None else 0.0
    dist_node = node.get("distribution")
    dist = dist_node.str(["uniform", "gauss"]) if dist_node is not None else "uniform"
    follows: tuple[tuple[str, float], ...] = ()
    if node.get("follows") is not None:
        follows = tuple((k, v.float()) for k, v in node["follows"].items())
    mean = node["mean"].float() if node.get("mean") is not None else 0.0
    lag = node["lag"].float(min=0.0) if node.get("lag") is not None else 0.0
    return ScalarModel(field_name, mean, noise, dist, follows, lag)
