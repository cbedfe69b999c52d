"""`make spy`: the jar of generated Java types holds every wire type, so lcm-spy decodes every channel."""

from __future__ import annotations

import subprocess
import zipfile

from conftest import REPO


def test_skelmsg_jar_has_every_lcm_type() -> None:
    built = subprocess.run(["make", "-s", "build/skelmsg.jar"], cwd=REPO, capture_output=True, text=True,
                           timeout=300)
    assert built.returncode == 0, built.stdout + built.stderr
    with zipfile.ZipFile(REPO / "build" / "skelmsg.jar") as jar:
        classes = {n.removesuffix(".class").split("/")[-1] for n in jar.namelist() if n.endswith(".class")}
    types = {p.stem for p in (REPO / "lcmtypes").glob("*.lcm")}
    assert types and types <= classes, types - classes
