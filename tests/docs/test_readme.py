"""README.md is the way in: short, the two commands literally, and every link it gives
leads to a file of the repository."""

from __future__ import annotations

import re

from conftest import REPO

README = REPO / "README.md"


def test_the_readme_is_short_and_gives_the_two_commands() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    for command in ("make demo", "make test"):
        assert re.search(rf"^{command}\b", text, re.MULTILINE), command


def test_every_link_of_the_readme_leads_to_a_file() -> None:
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README.read_text())
    assert links
    broken = [link for link in links if "://" not in link and not (REPO / link).exists()]
    assert not broken, broken
