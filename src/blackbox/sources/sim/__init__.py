"""The built-in simulated robot with fault injection (see docs/simulator.md)."""

from .faults import (
    FAULT_KINDS,
    THESIS_FAULT_KINDS,
    Fault,
    FaultKind,
    GroundTruth,
    load_faults,
    random_campaign,
    read_ground_truth,
    write_ground_truth,
)
from .messages import BytesModel, ImageModel, ScalarModel, ValueModel
from .robot import BUILTIN_ROBOTS, SimulatedSource, open_sim
from .topology import NodeSpec, TopicSpec, Topology

__all__ = [
    "BUILTIN_ROBOTS",
    "FAULT_KINDS",
    "THESIS_FAULT_KINDS",
    "BytesModel",
    "Fault",
    "FaultKind",
    "GroundTruth",
    "ImageModel",
    "NodeSpec",
    "ScalarModel",
    "SimulatedSource",
    "TopicSpec",
    "Topology",
    "ValueModel",
    "load_faults",
    "open_sim",
    "random_campaign",
    "read_ground_truth",
    "write_ground_truth",
]
