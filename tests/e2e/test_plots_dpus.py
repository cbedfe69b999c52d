"""plots.py and html.py on real runs: every PNG written and sane, report.html self-contained."""

from __future__ import annotations

import base64
import json
import re
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ASAN_DPU, EXAMPLES, fresh_url, skel

from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.export_mcap import export
from skeleton.analysis.views.plots import default_window_ns, write_plots
from skeleton.analysis.views.report import write_plot_dir

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ALL_PLOTS = ["utilization.png", "timeline.png", "schedule.png", "release_latency.png", "buffer_latency.png",
             "chain_latency.png"]  # fmt: skip


def _run(out: Path, system: Path, *extra: str) -> Path:
    url = fresh_url()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SKEL_DPU", str(ASAN_DPU))
        run = skel("run", str(system), "--spawn", "--url", url, "--out", str(out), *extra)
    assert run.returncode in (0, 3), run.stderr  # 3: a fault was measured; plots are still made
    return out / "run.lcm"


@pytest.fixture(scope="module")
def servo_log(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A short real SERVO run (it has chains); faster DPUs so a busy machine does not lock it out."""
    fast = [arg for d in (1, 2, 3, 4) for arg in ("-s", f"dpu.{d}.speed=3")]
    yield _run(tmp_path_factory.mktemp("servo") / "run", EXAMPLES / "servo.yaml", "--cycles", "300",
               "-s", "run.warmup_cycles=20", *fast)  # fmt: skip


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path.name} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_cli_writes_every_plot_and_a_self_contained_html(servo_log: Path, tmp_path: Path) -> None:
    out = tmp_path / "plots"
    result = skel("report", str(servo_log), "--plots", str(out))
    assert result.returncode in (0, 3), result.stderr
    assert "per DPU" in result.stdout and f"written to {out}" in result.stderr
    page = (out / "report.html").read_text()
    for name in ALL_PLOTS:
        width, height = _png_size(out / name)
        assert 600 <= width <= 2000 and 300 <= height <= 2000, (name, width, height)
        assert (out / name).stat().st_size > 10_000, f"{name} looks empty"
        encoded = base64.b64encode((out / name).read_bytes()).decode()
        assert f'src="data:image/png;base64,{encoded}"' in page, f"{name} not embedded"
    # the tables, every process and DPU, and nothing fetched from elsewhere
    for text in ("per DPU", "per process", "per buffer", "per chain", "executor", "jacobian_update"):
        assert text in page
    assert not re.search(r'(src|href)="(?!data:)', page)
    assert page.count("<img ") == len(ALL_PLOTS) and "names no chains" not in page


def test_a_run_without_chains_skips_the_chain_plot_with_a_note(tmp_path: Path) -> None:
    text = (EXAMPLES / "pair-10ms-5ms.yaml").read_text()
    system = tmp_path / "pair.yaml"
    system.write_text(text[: text.index("chains:")])
    log = _run(tmp_path / "run", system, "--cycles", "120")
    out = tmp_path / "plots"
    write_plot_dir(load_run(log), out, str(log))
    assert not (out / "chain_latency.png").exists()
    for name in ALL_PLOTS[:-1]:
        _png_size(out / name)
    page = (out / "report.html").read_text()
    assert "Chain latency: the system file names no chains" in page
    assert page.count("<img ") == len(ALL_PLOTS) - 1


def test_timeline_window_is_an_option(servo_log: Path, tmp_path: Path) -> None:
    data = load_run(servo_log)
    start, length = default_window_ns(data)
    assert length == 4 * 23_800_000  # 4 minor cycles of the slowest DPU (DPU 4)
    assert start > 0
    made = write_plots(data, tmp_path, window_ms=(10.0, 20.0))
    timeline = next(p for p in made.plots if p.name == "timeline.png")
    assert timeline.caption.startswith("20.0 ms")
    _png_size(tmp_path / "timeline.png")


def test_json_report_with_plots_keeps_stdout_json(servo_log: Path, tmp_path: Path) -> None:
    result = skel("report", str(servo_log), "--json", "--plots", str(tmp_path / "plots"))
    assert json.loads(result.stdout)["system"] == "servo"
    assert (tmp_path / "plots" / "report.html").exists()


def test_plots_from_the_mcap_export_are_the_same(servo_log: Path, tmp_path: Path) -> None:
    export(load_run(servo_log), tmp_path / "run.mcap")
    write_plot_dir(load_run(servo_log), tmp_path / "from-lcm", str(servo_log))
    write_plot_dir(load_run(tmp_path / "run.mcap"), tmp_path / "from-mcap", str(tmp_path / "run.mcap"))
    for name in ALL_PLOTS:
        mcap_png, lcm_png = (tmp_path / d / name for d in ("from-mcap", "from-lcm"))
        assert mcap_png.read_bytes() == lcm_png.read_bytes(), name
