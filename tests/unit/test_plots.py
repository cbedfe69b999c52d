"""tests/e2e/test_plots_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

from pathlib import Path

import pytest

from skeleton.analysis.views.report import report_command


def test_unreadable_log_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "junk.lcm"
    junk.write_bytes(b"not a log" * 30)
    code = report_command(junk, as_json=True, run_id=None, plots=tmp_path / "plots")
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "junk.lcm" in err
