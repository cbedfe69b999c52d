"""The maintainers' layout page (docs/design/layout.md) names every source file of the tree, by its stem."""

from __future__ import annotations

import re
import subprocess

from conftest import REPO


def _layout() -> str:
    page = (REPO / "docs" / "design" / "layout.md").read_text()
    return page[page.index("```") + 3:page.index("```", page.index("```") + 3)]


def test_the_layout_page_names_every_source_file_and_folder() -> None:
    layout = _layout()
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    sources = [p for p in tracked if re.fullmatch(r"(analysis|host|dpu|lcmtypes)/.*\.(py|c)", p)
               and not p.endswith("__init__.py")]
    assert sources
    missing = [p for p in sources if not re.search(rf"\b{re.escape(p.rsplit('/', 1)[1].rsplit('.', 1)[0])}\b",
                                                   layout)]
    assert not missing, f"docs/design/layout.md does not name: {missing}"
    folders = {p.split("/")[0] for p in tracked if "/" in p and not p.startswith(".")}
    assert not [f for f in folders if f"{f}/" not in layout], folders
