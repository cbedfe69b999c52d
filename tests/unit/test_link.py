"""A link's writers each get a group and a port of their own (host/sysfile/link.py): the host
derives them, the DPUs open only the writers they read, `skel check` refuses links whose
ports would meet or whose groups would leave the multicast range. The DPU side is checked
at its sockets (the ports a running DPU is bound to) and, across namespace hosts, at the
groups each host joined (tests/netns/test_netns_scale.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import skel

from skeleton.host.sysfile.link import group_overlap, record_url
from skeleton.host.sysfile.system import loads

THREE = """\
system: three
links:
  - {{name: bus, url: "{url}"}}
  - {{name: mem, url: local}}
dpus: [{{id: 1}}, {{id: 2}}, {{id: 3}}]
buffers:
  - {{id: 1, name: a, bytes: 64}}
  - {{id: 2, name: a2, bytes: 64}}
  - {{id: 3, name: b, bytes: 64}}
  - {{id: 4, name: c, bytes: 64, link: mem}}
processes:
  - {{id: 1, name: wa, dpu: 1, period_us: 10000, compute_us: 100, outputs: [a, a2]}}
  - {{id: 2, name: wb, dpu: 2, period_us: 10000, compute_us: 100, outputs: [b]}}
  - {{id: 3, name: reader, dpu: 3, period_us: 10000, compute_us: 100, inputs: [a], outputs: [c]}}
  - {{id: 4, name: local, dpu: 3, period_us: 10000, compute_us: 100, inputs: [c]}}
run: {{duration_s: {duration}, warmup_cycles: 2, lockout_cycles: 50}}
"""


BUS = "udpm://239.255.76.67:7700?ttl=0"


def _three(tmp_path: Path, url: str, duration: float = 1.0) -> Path:
    path = tmp_path / "three.yaml"
    path.write_text(THREE.format(url=url, duration=duration))
    return path


def test_each_writer_gets_the_next_port_of_its_link() -> None:
    system = loads(THREE.format(url="udpm://239.255.76.67:7700?ttl=0&recv_buf_size=300000", duration=1),
                   "three.yaml")
    # wa's two buffers share its group and port; wb has the next; a local buffer has no URL.
    assert system.buffer_url("a") == "udpm://239.255.76.68:7701?ttl=0&recv_buf_size=300000"
    assert system.buffer_url("a2") == system.buffer_url("a")
    assert system.buffer_url("b") == "udpm://239.255.76.69:7702?ttl=0&recv_buf_size=300000"
    assert system.buffer_url("c") == ""
    # LCM's defaults fill a URL that leaves the group and port out.
    bare = loads(THREE.format(url="udpm://", duration=1), "three.yaml")
    assert bare.buffer_url("b") == "udpm://239.255.76.69:7669"


def test_check_lists_the_ports_a_firewall_must_pass(tmp_path: Path) -> None:
    path = _three(tmp_path, "udpm://239.255.76.67:7700?ttl=1")
    done = skel("check", str(path), "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    ports = json.loads(done.stdout)["ports"]
    writers, groups = {"wa": 7701, "wb": 7702}, {"wa": "239.255.76.68", "wb": "239.255.76.69"}
    link = {"link": "bus", "group": "239.255.76.67", "port": 7700}
    assert ports == [{**link, "writers": writers, "groups": groups}]
    text = skel("check", str(path)).stdout
    assert ("link bus: 239.255.76.67:7700 (UDP); its writers' buffers on wa 239.255.76.68:7701, "
            "wb 239.255.76.69:7702") in text, text


def test_two_links_on_one_port_count_their_writers_on() -> None:
    system = loads(_with_side(BUS, BUS), "three.yaml")
    assert system.buffer_url("a").startswith("udpm://239.255.76.68:7701?")
    assert system.buffer_url("b").startswith("udpm://239.255.76.69:7702?")


@pytest.mark.parametrize(("second", "why"), [
    ("udpm://239.255.76.68:7701?ttl=0", "which meet link side's 7701..7701 (239.255.76.68)"),
    ("udpm://239.255.76.67:7702?ttl=0", "which meet link side's"),
])
def test_check_refuses_links_whose_ports_meet(tmp_path: Path, second: str, why: str) -> None:
    path = tmp_path / "clash.yaml"
    path.write_text(THREE.format(url="udpm://239.255.76.67:7700?ttl=0", duration=1).replace(
        "  - {name: mem, url: local}", f'  - {{name: mem, url: local}}\n  - {{name: side, url: "{second}"}}'))
    done = skel("check", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"{path}: links.bus.url: its writers' buffers take ports 7700..7702, "), line
    assert why in line, line


def test_check_refuses_writers_on_the_record_port(tmp_path: Path) -> None:
    """The first link's URL is the control URL; its record URL, a port below, is the DPUs'
    heartbeats and timing: a writer there would send every buffer to the host and logger."""
    path = tmp_path / "record.yaml"
    path.write_text(_with_side(BUS, "udpm://239.255.70.1:7698?ttl=0"))  # wb's buffers: 7699
    done = skel("check", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.strip() == (
        f"{path}: links.side.url: its writers' buffers take ports 7699..7699, which hold port 7699 of the "
        "record URL (udpm://239.255.76.66:7699?ttl=0: the DPUs' heartbeats and timing); put the link's "
        "port further from the control URL's")


def test_record_url_is_the_control_urls_group_and_port_less_one() -> None:
    """dpu/link.c's link_record_url holds to the same cases (tests/c/test_config.c)."""
    assert record_url("udpm://239.255.80.67:7667?ttl=0") == "udpm://239.255.80.66:7666?ttl=0"
    assert record_url("udpm://239.1.0.0:9000") == "udpm://239.0.255.255:8999"
    assert record_url("udpm://?ttl=1") == "udpm://239.255.76.66:7666?ttl=1"
    assert record_url("udpm://239.255.0.9?ttl=1") == "udpm://239.255.0.8:7666?ttl=1"
    assert record_url("udpm://239.255.0.9:?ttl=1") == "udpm://239.255.0.8:7666?ttl=1"
    assert record_url("udpm://239.255.0.9:0") == "udpm://239.255.0.8:7666"
    assert record_url("memq://") == "memq://"
    for bad in ("udpm://239.255.76.67:1", "udpm://224.0.0.0:7667"):
        with pytest.raises(ValueError, match="record URL"):
            record_url(bad)
    with pytest.raises(ValueError, match="not a multicast group"):
        record_url("udpm://240.0.0.1:7667")


def test_check_refuses_ports_past_65535(tmp_path: Path) -> None:
    path = _three(tmp_path, "udpm://239.255.76.67:65534?ttl=0")
    done = skel("check", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.strip() == f"{path}: links.bus.url: its writers need ports 65535..65536, past 65535"


@pytest.mark.parametrize(("group", "why"), [
    ("239.255.255.255", "its writers need groups 240.0.0.0..240.0.0.1, outside the multicast groups"),
    ("224.0.0.250", "its writers need groups 224.0.0.251..224.0.0.252, outside the multicast groups"),
    ("239.127.255.255", "its writers need groups 239.128.0.0..239.128.0.1, and 239.128.0.0 shares its "
                        "Ethernet address with 224.0.0.0, which switches flood"),
])
def test_check_refuses_writer_groups_a_switch_cannot_keep_apart(tmp_path: Path, group: str, why: str) -> None:
    path = _three(tmp_path, f"udpm://{group}:7700?ttl=0")
    done = skel("check", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"{path}: links.bus.url: {why}"), line


def _with_side(url: str, side: str) -> str:
    """THREE with wb's buffer on a second link, `side`."""
    return THREE.format(url=url, duration=1).replace(
        "  - {name: mem, url: local}", f'  - {{name: mem, url: local}}\n  - {{name: side, url: "{side}"}}'
    ).replace("{id: 3, name: b, bytes: 64}", "{id: 3, name: b, bytes: 64, link: side}")


def test_check_warns_of_links_whose_groups_meet(tmp_path: Path) -> None:
    """Two links on one group, their ports apart: valid (each buffer still reaches only its
    readers), but each link's writers get the same groups, which a snooping switch cannot
    keep apart: said once."""
    path = tmp_path / "shared.yaml"
    path.write_text(_with_side(BUS, "udpm://239.255.76.67:7800?ttl=0"))
    done = skel("check", str(path), "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    shared = [w for w in json.loads(done.stdout)["warnings"] if "groups" in w]
    assert shared == ["links bus and side share their writers' multicast groups 239.255.76.68.."
                      "239.255.76.68: a switch that snoops IGMP then sends each link's buffers on them to "
                      "the hosts of both; give link side a group from 239.255.76.69 on"], shared
    control = loads(_with_side(BUS, "udpm://239.255.76.66:7800?ttl=0"), "x.yaml")
    said = group_overlap(control.links, control.writer_ports, control.default_link.url)
    assert said is not None and said.startswith("link side's writers' groups 239.255.76.67..239.255.76.67 "
                                                 "hold the control group 239.255.76.67"), said
    record = loads(_with_side(BUS, "udpm://239.255.76.65:7800?ttl=0"), "x.yaml")  # the record group, .66
    said = group_overlap(record.links, record.writer_ports, record.default_link.url)
    assert said is not None and "hold the record group 239.255.76.66, which every host joins" in said, said
    apart = loads(_with_side(BUS, "udpm://239.255.76.69:7800?ttl=0"), "x.yaml")
    assert group_overlap(apart.links, apart.writer_ports, apart.default_link.url) is None
    together = loads(_with_side(BUS, BUS), "x.yaml")
    assert group_overlap(together.links, together.writer_ports, BUS) is None  # counted on together


def _many_writers(writers: int, events: bool) -> str:
    """DPU 1 reads the buffers of `writers` processes on DPUs 2 and 3 (16 inputs a reader)."""
    lines = ["system: many", "dpus: [{id: 1}, {id: 2}, {id: 3}]", "buffers:"]
    lines += [f"  - {{id: {w}, name: b{w}, bytes: 8}}" for w in range(1, writers + 1)]
    lines += ["processes:"]
    lines += [f"  - {{id: {w}, name: w{w}, dpu: {2 + w % 2}, period_us: 10000, compute_us: 10, "
              f"outputs: [b{w}]}}" for w in range(1, writers + 1)]  # fmt: skip
    for r, first in enumerate(range(1, writers + 1, 16)):
        inputs = ", ".join(f"b{w}" for w in range(first, min(first + 16, writers + 1)))
        emits = ", emits: [tick]" if events and r == 0 else ""
        lines += [f"  - {{id: {100 + r}, name: r{r}, dpu: 1, period_us: 10000, compute_us: 10, "
                  f"inputs: [{inputs}]{emits}}}"]
    if events:
        lines += ["  - {id: 99, name: ticked, dpu: 3, sync: event, event: tick, period_us: 1000, "
                  "compute_us: 10}"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(("writers", "events", "refused"), [
    (64, False, False), (65, False, True), (63, True, False), (64, True, True),
])
def test_check_refuses_a_dpu_that_needs_more_links_than_it_opens(
    tmp_path: Path, writers: int, events: bool, refused: bool
) -> None:
    """A DPU opens a link per writer it reads or is, and the control URL when it awaits or
    emits events (contract MAX_LINKS): more is refused by skel check, not at the push."""
    path = tmp_path / "many.yaml"
    path.write_text(_many_writers(writers, events))
    done = skel("check", str(path))
    assert done.returncode == (2 if refused else 0), done.stdout + done.stderr
    if refused:
        said = " and the control URL for its events" if events else ""
        assert done.stderr.strip() == (f"{path}: dpus.1: its processes read or write the buffers of "
                                       f"{writers} writers (a group and port each){said}; a DPU opens at "
                                       "most 64: spread its processes over more DPUs"), done.stderr
