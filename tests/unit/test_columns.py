"""tests/e2e/test_api.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

from conftest import REPO

from skeleton.analysis.measure.columns import COLUMNS


def test_the_readme_documents_every_column() -> None:
    readme = (REPO / "README.md").read_text()
    for table, columns in COLUMNS.items():
        for column, text in columns.items():
            assert f"`{column}` {text}" in readme, (table, column)
