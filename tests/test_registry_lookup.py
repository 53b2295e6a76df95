"""Looking up one plug-in by name imports its own module, not the whole package.

Every process that starts a ``blackbox`` command pays for what it imports; the ROS 2
source alone brings Cyclone DDS (0.2 s of CPU). A lookup of ``sim`` therefore imports
``blackbox.sources.sim`` and no other source, and the whole package is imported only when
the name is not a module's own (an alias, a typo) or when every entry is asked for.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from blackbox.registry import Registry

PLUGIN = """\
from {package} import REGISTRY
REGISTRY.add({name!r}, {name!r} + " entry")
"""


def make_package(root: Path, package: str, names: list[str]) -> None:
    """A package holding a registry and one module per name, each registering itself."""
    folder = root / package
    folder.mkdir()
    (folder / "__init__.py").write_text(
        "from blackbox.registry import Registry\n"
        f"REGISTRY = Registry('toy', {package!r})\n", encoding="utf-8")
    for name in names:
        (folder / f"{name}.py").write_text(PLUGIN.format(package=package, name=name),
                                           encoding="utf-8")


@pytest.fixture
def toy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Registry[str]]:
    package = f"toy_plugins_{tmp_path.name.replace('-', '_')}"
    make_package(tmp_path, package, ["alpha", "beta"])
    monkeypatch.syspath_prepend(str(tmp_path))
    module = __import__(package)
    registry: Registry[str] = module.REGISTRY
    yield registry
    for name in [m for m in sys.modules if m == package or m.startswith(package + ".")]:
        del sys.modules[name]


def test_a_lookup_imports_the_plugins_own_module_only(toy: Registry[str]) -> None:
    package = toy._package
    assert toy.get("alpha") == "alpha entry"
    assert f"{package}.alpha" in sys.modules
    assert f"{package}.beta" not in sys.modules


def test_an_unknown_name_and_a_listing_load_every_module(toy: Registry[str]) -> None:
    assert toy.get("gamma") is None
    assert list(toy) == ["alpha", "beta"]


def test_a_listing_after_a_lookup_still_has_every_entry_once(toy: Registry[str]) -> None:
    assert toy.get("beta") == "beta entry"
    assert toy.items() == [("alpha", "alpha entry"), ("beta", "beta entry")]


def test_opening_the_simulator_imports_no_middleware() -> None:
    """In a fresh interpreter, as a ``blackbox run`` of the simulator starts."""
    probe = ("import sys\n"
             "from blackbox.sources import open_source\n"
             "open_source('sim:thesis')\n"
             "print(sorted(m for m in ('cyclonedds', 'blackbox.sources.ros2', "
             "'blackbox.sources.ros1', 'blackbox.sources.bag') if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
