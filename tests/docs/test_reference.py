"""The generated reference names everything the code defines: every field of the system
file's schema, every option of every command, every exit code, every column of the Python
tables and every field of report.json. A field added without its place in the reference
fails here, and so does a generator that lost a section."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import typing
from types import ModuleType

import pytest
from conftest import REPO


@pytest.fixture(scope="module")
def hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("docs_hooks", REPO / "docs" / "hooks.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _page(hooks: ModuleType, name: str) -> str:
    text = hooks.generate((REPO / "docs" / "reference" / name).read_text())
    assert "<!-- generated:" not in text
    return text


def _section(page: str, heading: str) -> str:
    """The text under a heading, up to the next heading of its level."""
    start = page.index(heading) + len(heading)
    end = page.find("\n### ", start)
    return page[start:] if end < 0 else page[start:end]


def test_every_schema_field_is_in_the_system_file_reference(hooks: ModuleType) -> None:
    page, src = _page(hooks, "system-file.md"), hooks._sources()
    models, todo = set(), [src.system_spec]
    while todo:
        model = todo.pop()
        if model not in models:
            models.add(model)
            for name in model.model_fields:
                todo += hooks._models(hooks._annotation(model, name))
    assert len(models) >= 10
    for model in models:
        section = _section(page, f"### {model.__name__}\n")
        for name, info in model.model_fields.items():
            assert f"| `{name}` |" in section, (model.__name__, name)
            assert info.description, f"{model.__name__}.{name} has no description (a docstring under it)"


def test_every_option_of_every_command_is_in_the_cli_reference(hooks: ModuleType) -> None:
    page, src = _page(hooks, "cli.md"), hooks._sources()
    commands = list(hooks._subparsers(src.build_parser()))
    assert len(commands) >= 14
    for name, _, sub in commands:
        section = _section(page, f"### skel {name}\n")
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            for option in action.option_strings or [action.metavar or action.dest]:
                assert f"`{option}`" in section, (name, option)
    for code in ("0", "1", "2", "3", "130", "141"):
        assert f"| {code} | `EXIT_" in page, code


def test_every_column_and_report_field_is_in_the_report_reference(hooks: ModuleType) -> None:
    page, src = _page(hooks, "report.md"), hooks._sources()
    for table, columns in src.columns.COLUMNS.items():
        assert f"### {table}\n" in page
        for column, text in columns.items():
            assert f"| `{column}` | {hooks._cell(text)} |" in page, (table, column)

    def fields(cls: type, prefix: str) -> typing.Iterator[str]:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            yield prefix + f.name
            for inner in hooks._dataclasses(hints[f.name]):
                if inner is not cls:
                    mark = "[]" if typing.get_origin(hints[f.name]) is list else ""
                    yield from fields(inner, f"{prefix}{f.name}{mark}.")
    names = list(fields(src.run_report, ""))
    assert "dpus[].compute_pct" in names and "integrity.lost_batches" in names
    for name in names:
        if name.count(".") <= 2:  # what nests deeper is listed once, under its first parent
            assert f"| `{name}` |" in page or f".{name.rsplit('.', 1)[1]}` |" in page, name
