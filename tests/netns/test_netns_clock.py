"""Clock offsets across hosts: DPUs on two namespace hosts with shifted clocks, the estimator on a third."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from conftest import ASAN_DPU, REPO, SANITIZER_ERROR

from netns import Hosts, hosts_fixture

netns_hosts = hosts_fixture(3)

URL = "udpm://239.255.76.67:7667?ttl=1"  # inside the namespaces no other test shares it
TOLERANCE_NS = 200_000


def test_netns_clock_offsets_recovered_across_hosts(netns_hosts: Hosts, tmp_path) -> None:  # type: ignore[no-untyped-def]
    daemons = []
    for host, dpu, offset in (("skelh1", 1, 5_000_000), ("skelh2", 2, -3_000_000)):
        with open(tmp_path / f"dpu{dpu}.log", "wb") as log:
            daemons.append(netns_hosts.popen(host, [str(ASAN_DPU), "--id", str(dpu), "--url", URL,
                                                    "--clock-offset-ns", str(offset)],
                                             stdout=log, stderr=subprocess.STDOUT))
    time.sleep(0.5)
    done = netns_hosts.run("skelh3", [sys.executable, "-m", "skeleton.host.cli", "clock", "--url", URL,
                                      "--json", "--samples", "12"],
                           capture_output=True, text=True, cwd=REPO, timeout=60)
    for daemon in daemons:
        daemon.terminate()
        assert daemon.wait(timeout=10) == 0
    for log in tmp_path.glob("dpu*.log"):
        assert not SANITIZER_ERROR.search(log.read_bytes()), log.read_text(errors="replace")
    assert done.returncode == 0, done.stdout + done.stderr
    found = {row["dpu"]: row for row in json.loads(done.stdout)}
    assert sorted(found) == [1, 2], (found, [p.read_text() for p in tmp_path.glob("*.log")])
    assert abs(found[1]["offset_ns"] - 5_000_000) < TOLERANCE_NS, found[1]
    assert abs(found[2]["offset_ns"] + 3_000_000) < TOLERANCE_NS, found[2]
    for row in found.values():
        print(f"DPU {row['dpu']}: offset {row['offset_ns'] / 1e3:+.1f} µs, rtt {row['rtt_ns'] / 1e3:.1f} µs")
        assert 0 <= row["rtt_ns"] < 100_000_000
