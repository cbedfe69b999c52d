"""skel doctor: each check on made-up input, then the whole doctor inside broken and healthy hosts."""

from __future__ import annotations

import io

import pytest

from skeleton.host.cli.doctor import (
    Check,
    check_route,
    check_rp_filter,
    check_socket_buffers,
    check_ttl,
    doctor,
    firewall_findings_iptables,
    firewall_findings_nft,
    network_findings,
    parse_url,
)
from skelmsg.contract import DEFAULT_URL

URL1 = "udpm://239.255.76.67:7667?ttl=1"
LAB = parse_url(URL1)


# --- the checks on their own (no root needed) ------------------------------------------------
def test_parse_url_fills_lcm_defaults() -> None:
    assert parse_url("udpm://239.255.76.67:7700?ttl=1").port == 7700
    assert parse_url("udpm://") == parse_url(DEFAULT_URL)
    assert parse_url("udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304").recv_buf_size == 4194304
    assert parse_url("memq://").provider == "memq"


@pytest.mark.parametrize(("url", "why"), [("udpm://10.0.0.1:7667", "not a multicast group"),
                                          ("udpm://239.255.76.67:7667?ttl=x", "expected a whole number"),
                                          ("udpm://239.255.76.67:7667?ttl=300", "ttl=300")])
def test_parse_url_says_what_is_wrong(url: str, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        parse_url(url)


def test_bad_url_is_one_fail_line_and_exit_1() -> None:
    out = io.StringIO()
    assert doctor("udpm://10.0.0.1:7667", out) == 1
    assert out.getvalue().startswith("FAIL  url")


def test_ttl0_warns_that_it_never_leaves_the_host() -> None:
    check = check_ttl(parse_url(DEFAULT_URL))
    assert (check.level, check.fix) == ("WARN", "--url 'udpm://239.255.76.67:7667?ttl=1'")
    assert check_ttl(LAB).ok


def test_missing_route_suggests_lo_for_ttl0_and_the_interface_for_a_lab() -> None:
    local = check_route(parse_url(DEFAULT_URL), None, "lo")
    assert local.fix == "ip route add 224.0.0.0/4 dev lo"
    assert check_route(LAB, None, "eth1").fix == "ip route add 224.0.0.0/4 dev eth1"
    assert check_route(LAB, "lo", "eth1").level == "WARN"  # ttl=1 out of lo reaches nobody


def test_rp_filter_takes_the_larger_of_all_and_the_interface() -> None:
    assert check_rp_filter(LAB, "eth0", 1, 0).level == "WARN"
    assert check_rp_filter(LAB, "eth0", 0, 1).level == "WARN"
    assert check_rp_filter(LAB, "eth0", 2, 0).ok
    assert check_rp_filter(parse_url("udpm://"), "eth0", 1, 1).ok  # ttl=0: looped back only


def test_small_socket_buffers_warn_with_the_sysctl_fix() -> None:
    check = check_socket_buffers(212992, 212992)
    assert check.level == "WARN" and "rmem_max=212992" in check.detail
    assert check.fix == "sysctl -w net.core.rmem_max=8388608 net.core.rmem_default=8388608"
    assert check_socket_buffers(8388608, 8388608).ok
    assert not check_socket_buffers(8388608, 8388608, recv_buf_size=16777216).ok


NFT = """table inet filter { # handle 3
\tchain input { # handle 1
\t\ttype filter hook input priority filter; policy drop;
\t\tudp dport 7667 drop # handle 4
\t\ttcp dport 22 accept # handle 5
\t\tudp dport { 53, 7000-7700 } reject # handle 6
\t\tudp dport 9999 drop # handle 7
\t\tip daddr 224.0.0.0/4 drop # handle 8
\t\tudp dport 7667 numgen random mod 100 < 5 drop # handle 9
\t}
}
"""


def test_nft_rules_that_drop_lcm_are_found_with_their_delete_command() -> None:
    found = firewall_findings_nft(NFT, LAB)
    fixes = [c.fix for c in found]
    assert "nft insert rule inet filter input udp dport 7667 accept" in fixes  # policy drop
    for handle in (4, 6, 8, 9):
        assert f"nft delete rule inet filter input handle {handle}" in fixes
    assert "nft delete rule inet filter input handle 7" not in fixes  # another port
    levels = {c.fix.rsplit(" ", 1)[-1]: c.level for c in found}
    assert levels["4"] == "FAIL" and levels["9"] == "WARN"  # random loss is a warning


def test_iptables_rules_that_drop_lcm_are_found_with_their_delete_command() -> None:
    saved = ("*filter\n:INPUT DROP [0:0]\n-A INPUT -p udp -m udp --dport 7667 -j DROP\n"
             "-A INPUT -p udp -m udp --dport 53 -j DROP\nCOMMIT\n")
    fixes = [c.fix for c in firewall_findings_iptables(saved, LAB)]
    assert fixes == ["iptables -t filter -I INPUT -p udp --dport 7667 -j ACCEPT",
                     "iptables -t filter -D INPUT -p udp -m udp --dport 7667 -j DROP"]


def test_check_level_names() -> None:
    assert Check("x", True, "").level == "OK"
    assert Check("x", False, "", severity="warn").level == "WARN"


def test_a_runs_shaping_is_named_with_its_undo_and_is_no_firewall_finding() -> None:
    ours = ("table inet skl0e5c6f8a {\n\tchain in {\n\t\tip daddr 239.255.76.73 udp dport 7667 "
            "numgen random mod 1000000 < 50000 drop # handle 3\n\t}\n}\n")
    shaped = NFT.replace("table inet filter {", ours + "table inet filter {")
    assert firewall_findings_nft(shaped, LAB) == firewall_findings_nft(NFT, LAB)
    can, applied = network_findings(False, {"skl7d3b26fe": "qdisc tbf 8001: root rate 1Mbit"},
                                    ["skl0e5c6f8a"])
    assert can.ok and "no netem" in can.detail and "emulated by the DPUs" in can.detail
    assert applied.level == "WARN" and "qdisc tbf" in applied.detail
    assert applied.fix == ("only when no run is going on: ip link del skl7d3b26fe; "
                           "nft delete table inet skl0e5c6f8a")
    assert [c.detail[:5] for c in network_findings(True, {}, [])] == ["netem"]
