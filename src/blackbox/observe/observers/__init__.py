"""The built-in observer types, one module each; each registers itself in
:data:`~blackbox.observe.base.OBSERVERS`, which imports every module here when first read.

``quantity`` (filtered quantities, state verdicts, the judged-observer base) and ``entry``
(reading the keys every entry shares) are their common parts.
"""

from blackbox.observe.observers.activated import ActivatedObserver
from blackbox.observe.observers.fields import FieldsObserver
from blackbox.observe.observers.hz import HzObserver
from blackbox.observe.observers.moving import MotionSource, MovingObserver
from blackbox.observe.observers.network import NetworkObserver
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver
from blackbox.observe.observers.resources import ResourcesObserver
from blackbox.observe.observers.scores import ScoresObserver
from blackbox.observe.observers.timeout import TimeoutObserver
from blackbox.observe.observers.timestamp import TimestampObserver
from blackbox.observe.observers.timing import TimingObserver
from blackbox.observe.observers.velocity import VelocityObserver

__all__ = [
    "ActivatedObserver",
    "FieldsObserver",
    "FilteredQuantity",
    "HzObserver",
    "JudgedObserver",
    "MotionSource",
    "MovingObserver",
    "NetworkObserver",
    "ResourcesObserver",
    "ScoresObserver",
    "TimeoutObserver",
    "TimestampObserver",
    "TimingObserver",
    "VelocityObserver",
]
