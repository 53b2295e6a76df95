"""network observer: rx/tx rates from cumulative interface counters."""

from __future__ import annotations

import pytest

import blackbox.observe.observers  # noqa: F401  (registers the observer types)
from blackbox.config.node import ConfigError, ConfigNode
from blackbox.events import Interest, NetworkSample
from blackbox.model import Code, Resource, State
from blackbox.observe.base import OBSERVERS

CONFIG = """\
type: network
interface: eth0
rx_filter: {type: mean, window_size: 2}
tx_filter: {type: mean, window_size: 2}
states:
  - number: 1
    name: light
    rx: {value: {type: less_than, less_than: 1000000}}
    tx: {value: {type: less_than, less_than: 1000000}}
"""


def build(text: str = CONFIG):
    return OBSERVERS["network"].build(ConfigNode.parse(text, "t.yaml"))


def test_rates_between_consecutive_samples() -> None:
    net = build()
    net.on_network(NetworkSample(0.0, "eth0", 1_000, 5_000))
    net.on_network(NetworkSample(1.0, "eth0", 11_000, 7_000))   # 10000 B/s, 2000 B/s
    net.on_network(NetworkSample(3.0, "eth0", 51_000, 11_000))  # 20000 B/s, 2000 B/s
    [obs] = net.evaluate(3.0)
    assert obs.code == Code.GENERAL_OK
    assert obs.resource == Resource(interface="eth0")
    assert obs.states == (State(1, "light"),)
    assert obs.values["rx"] == 15_000.0
    assert obs.values["tx"] == 2_000.0
    assert obs.message == "rx 15 kB/s, tx 2 kB/s fits 'light'"


def test_heavy_traffic_fits_no_state() -> None:
    net = build()
    net.on_network(NetworkSample(0.0, "eth0", 0, 0))
    net.on_network(NetworkSample(0.5, "eth0", 2_000_000, 0))
    [obs] = net.evaluate(1.0)
    assert obs.code == Code.NO_STATE_FITS
    assert obs.values["rx"] == 4_000_000.0


def test_counter_reset_is_skipped() -> None:
    net = build()
    net.on_network(NetworkSample(0.0, "eth0", 900_000, 900_000))
    net.on_network(NetworkSample(1.0, "eth0", 1_000, 1_000))  # reset: no rate
    [obs] = net.evaluate(1.0)
    assert obs.code == Code.NOT_AVAILABLE
    assert obs.message == "waiting for a second sample (rates need two) of interface eth0"
    net.on_network(NetworkSample(2.0, "eth0", 3_000, 1_500))
    [obs] = net.evaluate(2.0)
    assert obs.values["rx"] == 2_000.0
    assert obs.values["tx"] == 500.0


def test_other_interfaces_and_repeated_times_are_ignored() -> None:
    net = build()
    net.on_network(NetworkSample(0.0, "wlan0", 0, 0))
    [obs] = net.evaluate(0.5)
    assert obs.message == "waiting for the first sample of interface eth0"
    net.on_network(NetworkSample(1.0, "eth0", 0, 0))
    net.on_network(NetworkSample(1.0, "eth0", 500, 500))
    net.on_network(NetworkSample(2.0, "eth0", 1_000, 0))
    [obs] = net.evaluate(2.0)
    assert obs.values["rx"] == 1_000.0


def test_interest_and_describe() -> None:
    net = build()
    assert net.interest() == Interest(network=True)
    assert net.describe().startswith("network eth0: mean (window 2, deviation std_deviation) "
                                     "of rx, mean (window 2")


def test_config_errors() -> None:
    with pytest.raises(ConfigError, match="missing required key 'interface'"):
        build("type: network\n")
    with pytest.raises(ConfigError) as err:
        build("type: network\ninterface: eth0\nstates:\n  - {number: 1, name: x, rate: {}}\n")
    assert err.value.line == 4
    assert "unknown key 'rate'" in err.value.message
