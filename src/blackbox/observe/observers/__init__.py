"""The built-in observer types; importing this package registers each under its type name.

One module per type. ``quantity`` (filtered quantities and state verdicts) and ``entry``
(reading the keys every entry shares) are their common parts.
"""

from blackbox.observe.observers.activated import ActivatedObserver
from blackbox.observe.observers.fields import FieldsObserver
from blackbox.observe.observers.hz import HzObserver
from blackbox.observe.observers.moving import MotionSource, MovingObserver
from blackbox.observe.observers.network import NetworkObserver
from blackbox.observe.observers.quantity import FilteredQuantity
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
