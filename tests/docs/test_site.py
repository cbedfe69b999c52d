"""The documentation site builds with warnings as errors (`make docs`): a broken link, a
page missing from the navigation or a generator that fails breaks `make test`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from conftest import REPO


def test_the_site_builds_strict(tmp_path: Path) -> None:
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    for page in ("reference/system-file", "reference/cli", "reference/report", "tutorial/first-experiment"):
        assert (tmp_path / "site" / page / "index.html").exists(), page
