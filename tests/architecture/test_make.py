"""The Makefile's set-up, run for real: `make test` installs what the multi-host and browser
tests run (as root, with apt-get), the tests find the sanitizer DPU built after a plain `make`, and a test
whose command is missing skips with the reason."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import ASAN_DPU, REPO
from netns import require_command

MAKE = shutil.which("make")


def _stub(bin_dir: Path, name: str, script: str) -> None:
    path = bin_dir / name
    path.write_text("#!/bin/sh\n" + script)
    path.chmod(0o755)


def test_make_test_installs_ip_nft_and_chromium_as_root(tmp_path: Path) -> None:
    """On a fresh Debian machine as root neither `ip` nor `nft` nor Chromium is there: `make test`
    (its test-tools step) installs iproute2, nftables, chromium and chromium-driver (the console's
    browser tests) with apt-get, once, before the tests."""
    assert MAKE is not None
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "apt-get.calls"
    _stub(bin_dir, "id", "echo 0\n")  # root
    _stub(bin_dir, "apt-get", f'echo "$*" >> {calls}\n')
    # Only the stubs on PATH: as on a machine without ip and nft.
    done = subprocess.run([MAKE, "-s", "--no-print-directory", "test-tools"], cwd=REPO, capture_output=True,
                          text=True, env={**os.environ, "PATH": str(bin_dir)}, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr
    assert calls.read_text().splitlines() == [
        "update -qq", "install -y -qq iproute2 nftables chromium chromium-driver"]


def test_make_test_installs_nothing_when_everything_is_there(tmp_path: Path) -> None:
    assert MAKE is not None
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "apt-get.calls"
    _stub(bin_dir, "id", "echo 0\n")
    _stub(bin_dir, "apt-get", f'echo "$*" >> {calls}\n')
    for present in ("ip", "nft", "chromium", "chromedriver"):
        _stub(bin_dir, present, "exit 0\n")
    done = subprocess.run([MAKE, "-s", "--no-print-directory", "test-tools"], cwd=REPO, capture_output=True,
                          text=True, env={**os.environ, "PATH": str(bin_dir)}, timeout=60)
    assert done.returncode == 0 and not calls.exists(), done.stdout + done.stderr


def test_the_ci_script_is_make_test() -> None:
    lines = [ln for ln in (REPO / ".ci" / "run").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    assert lines[-1] == "make test" and not any("apt-get" in ln for ln in lines), lines


def test_the_sanitizer_dpu_is_built_and_current_for_any_pytest_run() -> None:
    """After a plain `make` there is no build/asan/skel-dpu: the session has make build it
    (and rebuild it when dpu/ changed), so `pytest -k netns` does not exit 127 in every DPU."""
    assert MAKE is not None
    assert ASAN_DPU.exists()
    up_to_date = subprocess.run([MAKE, "-q", str(ASAN_DPU.relative_to(REPO))], cwd=REPO, capture_output=True,
                                timeout=60)
    assert up_to_date.returncode == 0, "build/asan/skel-dpu is older than its sources"


def test_a_missing_command_skips_with_its_reason() -> None:
    with pytest.raises(pytest.skip.Exception, match=r"`no-such-tool` is not installed \(Debian no-such-pkg"):
        require_command("no-such-tool", "no-such-pkg")
