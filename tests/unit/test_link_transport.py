"""A link's emulated transport through the host's layers: the file, the wire, the file again, the
model's figures and the prediction (tests/sim/test_links.py runs it)."""

from __future__ import annotations

import pytest
from conftest import EXAMPLES

import skelmsg
from skeleton.host.live.wire import config_message, dump_yaml
from skeleton.host.model import Link, LossBurst, from_config
from skeleton.host.sysfile.system import load, loads
from skeleton.host.theory.predict import predict

HOP = EXAMPLES / "wireless-hop.yaml"


def test_the_transport_goes_through_the_wire_and_back_into_a_file_unchanged() -> None:
    system = load(HOP)
    radio = system.link("radio")
    assert (radio.latency_us, radio.jitter_us, radio.jitter) == (2000, 300, "normal")
    assert radio.burst == LossBurst(0.25, 25.0, 100.0)
    wire = skelmsg.config_t.decode(config_message(system, 1, 1, False).encode())
    back = {link.name: link for link in from_config(wire).links}
    assert back["radio"].latency_us == 2000 and back["radio"].burst == radio.burst
    assert back["radio"].jitter == "normal" and back["bus"].burst is None
    assert loads(dump_yaml(system), "again.yaml").links == system.links


def test_a_links_delay_and_long_run_loss() -> None:
    uniform = Link(1, "a", "local", latency_us=2000, jitter_us=500)
    assert uniform.delay_us == (1500.0, 2000.0, 2500.0)
    normal = Link(1, "a", "local", latency_us=1000, jitter_us=500, jitter="normal")
    assert normal.delay_us == (0.0, 1000.0, 2500.0)  # cut at 3 sigma, never below 0
    assert Link(1, "a", "local", loss_pct=5).mean_loss_pct == 5
    bursty = Link(1, "a", "local", loss_pct=1, burst=LossBurst(1, 9, 50))
    assert bursty.mean_loss_pct == pytest.approx(0.9 * 1 + 0.1 * 50)


def test_the_prediction_puts_the_delay_into_each_input_and_chain() -> None:
    pred = predict(load(HOP))
    scan = next(i for i in pred.inputs if i.buffer == "scan")
    assert scan.transport_us == 2000 and scan.lost_pct == pytest.approx(100 * 0.25 / 25.25)
    assert next(i for i in pred.inputs if i.buffer == "scan_copy").transport_us == 0
    (chain,) = pred.chains
    plain = predict(loads(HOP.read_text().replace("latency_us: 2000", "latency_us: 0")
                          .replace("jitter_us: 300", "jitter_us: 0"), "plain.yaml")).chains[0]
    assert chain.network_us == 2000 and plain.network_us == 0
    assert chain.best_us == plain.best_us + 1100  # the least delay: 2000 - 3 x 300
    assert chain.worst_us == pytest.approx(plain.worst_us + 2900)  # the most
