"""benchmarks/render_bench.py: the reading computed from the table's rows, and PyTorch3D left out when absent."""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType

import pytest
from benchmark_scripts import load_benchmark


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_benchmark("render_bench")


def _row(threads: int, **times: float) -> dict:
    return {"faces": 9800, "size": 299, "batch": 1, "threads": threads, **times}


def test_a_speed_up_is_their_time_over_ours_at_one_thread(bench: ModuleType) -> None:
    rows = [
        _row(1, meshadv_fwd=0.002, p3d_fwd=0.2),
        _row(1, meshadv_fwd=0.004, p3d_fwd=2.0),
        _row(2, meshadv_fwd=0.001, p3d_fwd=9.0),  # two threads: not in the one-thread range
        _row(1, meshadv_fwd=0.003),  # no PyTorch3D cell
    ]
    assert bench.speedup_range(rows, "meshadv_fwd", "p3d_fwd") == "100.0-500.0x"
    assert bench.speedup_range(rows, "meshadv_fwd", "torch_fwd") is None


def test_the_reading_names_only_the_renderers_that_were_timed(bench: ModuleType) -> None:
    rows = [_row(1, meshadv_fwd=0.01, meshadv_bwd=0.02, torch_fwd=0.02, torch_bwd=0.01)]
    text = bench.reading(rows)
    assert "forward 2.0-2.0x over the PyTorch rasterizer" in text
    assert "fwd+bwd 0.5-0.5x over the PyTorch rasterizer" in text
    assert "over PyTorch3D" not in text and "Mitsuba" not in text
    assert "forward 10.0 ms, forward + backward 20.0 ms" in text


def test_pytorch3d_that_cannot_be_imported_is_reported_not_raised(
    bench: ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "pytorch3d", None)  # makes `import pytorch3d` raise ImportError
    version, message = bench.probe_pytorch3d()
    assert version is None and "PYTHONPATH" in message


def test_the_deodr_section_gives_the_ratios_of_the_medians(bench: ModuleType) -> None:
    comparison = load_benchmark("deodr_comparison")
    rows = [{"scene": "icosphere", "faces": 5120, "size": 299, "antialias": 2, "nmr": 0.040, "local": 0.010,
             "deodr": 0.020, "nmr_torch_share": 0.3, "local_torch_share": 0.5},
            {"scene": "bunny", "faces": 10235, "size": 224, "antialias": 1, "nmr": 0.030, "local": 0.015,
             "nmr_torch_share": 0.2, "local_torch_share": 0.25}]
    text = comparison.section(rows, "python benchmarks/render_bench.py --deodr", "a machine", "0.2.3")
    assert "| icosphere | 5120 | 299 | 2 | 40.0 | 10.0 | 20.0 | 2.00 | 0.50 | 30% | 50% |" in text
    assert "| bunny | 10235 | 224 | 1 | 30.0 | 15.0 | – | – | – | 20% | 25% |" in text
    assert "at antialias 2, local / DEODR 0.50-0.50 and NMR / DEODR 2.00-2.00" in text
    assert "at antialias 1, local / DEODR –" in text and "torch share of meshadv's call 20%-50%" in text


def test_deodr_that_cannot_be_imported_is_reported_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    comparison = load_benchmark("deodr_comparison")
    monkeypatch.setitem(sys.modules, "deodr", None)
    version, message = comparison.probe_deodr()
    assert version is None and "pip install deodr" in message


def test_a_second_section_is_written_beside_the_first(bench: ModuleType, tmp_path: Path) -> None:
    out = tmp_path / "RESULTS.md"
    bench.write_section(out, "## Renderer\nA")
    bench.write_section(out, "## DEODR\nB", bench.DEODR_MARKS)
    bench.write_section(out, "## DEODR\nC", bench.DEODR_MARKS)
    text = out.read_text()
    assert "## Renderer\nA" in text and "## DEODR\nC" in text and "## DEODR\nB" not in text
