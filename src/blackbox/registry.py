"""Named plug-ins of one kind (observers, filters, checks, sources), in one style.

A plug-in is one module that defines its kind and registers it at import with
``REGISTRY.add(name, entry)``. A registry that names a ``package`` imports every module of
that package the first time it is read, the way the command line finds its commands, so a
built-in plug-in needs no import line anywhere else; looking up one name imports the module
of that name first and the rest only if it does not register it. A plug-in outside the package (a
test's throw-away observer, a site's own source) registers the same way: importing its
module is enough.

Each entry may carry an ``example``: a configuration mapping that builds it. The contract
tests (``tests/test_observe_contracts.py``) build every registered kind from its example
and check the behaviour all kinds share, so a kind registered without one fails there.
"""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
from collections.abc import Iterator, Mapping
from typing import Generic, TypeVar

T = TypeVar("T")


class Registry(Generic[T]):
    """Entries by name. Reading it (``get``, ``in``, iteration) first loads ``package``."""

    def __init__(self, what: str, package: str | None = None) -> None:
        self.what = what
        self._package = package
        self._loaded = package is None
        self._entries: dict[str, T] = {}
        self._examples: dict[str, Mapping[str, object]] = {}

    def add(self, name: str, entry: T, example: Mapping[str, object] | None = None) -> T:
        """Register ``entry`` under ``name``, with an ``example`` configuration that builds
        it; a name registered twice is a programming error."""
        if name in self._entries:
            raise ValueError(f"{self.what} {name!r} registered twice")
        self._entries[name] = entry
        if example is not None:
            self._examples[name] = example
        return entry

    def example(self, name: str) -> Mapping[str, object] | None:
        """The example configuration ``name`` was registered with, if any."""
        self._all()
        return self._examples.get(name)

    def remove(self, name: str) -> None:
        """Forget ``name`` (for tests that register a throw-away plug-in)."""
        self._entries.pop(name, None)
        self._examples.pop(name, None)

    def get(self, name: str) -> T | None:
        """The entry ``name``. A plug-in usually lives in the package's module of its own
        name (``sim`` in ``blackbox.sources.sim``): that module alone is imported first, and
        the whole package only when it does not register ``name``. A ``blackbox run`` of the
        simulator then does not import the ROS 2 source and Cyclone DDS (0.2 s of CPU at
        every start of a process)."""
        if not self._loaded and name not in self._entries:
            self._load_own_module(name)
        if name in self._entries:
            return self._entries[name]
        return self._all().get(name)

    def _load_own_module(self, name: str) -> None:
        if self._package is None or not name.isidentifier():
            return
        module = f"{self._package}.{name}"
        try:
            found = importlib.util.find_spec(module) is not None
        except ModuleNotFoundError:
            found = False
        if found:
            importlib.import_module(module)

    def __getitem__(self, name: str) -> T:
        return self._all()[name]

    def __contains__(self, name: object) -> bool:
        return name in self._all()

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._all()))

    def __len__(self) -> int:
        return len(self._all())

    def items(self) -> list[tuple[str, T]]:
        return sorted(self._all().items())

    def _all(self) -> dict[str, T]:
        if not self._loaded:
            self._loaded = True
            self._load()
        return self._entries

    def _load(self) -> None:
        assert self._package is not None
        package = importlib.import_module(self._package)
        for info in pkgutil.iter_modules(package.__path__):
            if not info.name.startswith("_"):
                importlib.import_module(f"{self._package}.{info.name}")
