"""benchmarks/raster_cpu_time.py: its variant syntax, and a real (tiny) timing of a stand-in bench binary."""

from __future__ import annotations

import argparse
import stat
import sys
from pathlib import Path

import pytest
from benchmark_scripts import load_benchmark

bench = load_benchmark("raster_cpu_time")


def test_a_variant_names_its_label_binary_and_instruction_set() -> None:
    assert bench.parse_variant("new=/tmp/b:avx2") == ("new", "/tmp/b", "avx2")
    assert bench.parse_variant("old=/tmp/b") == ("old", "/tmp/b", "")


@pytest.mark.parametrize("text", ["/tmp/b", "=/tmp/b", "x=", "x=/tmp/b:sse9"])
def test_a_malformed_variant_is_rejected_naming_it(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="variant"):
        bench.parse_variant(text)


def test_per_call_time_subtracts_the_start_up_run(tmp_path: Path) -> None:
    # A stand-in "bench" that burns CPU in proportion to BENCH_REPS: the per-call time must be positive and far below
    # the start-up cost of a Python process, which the BENCH_REPS=1 run subtracts.
    script = tmp_path / "fake_bench"
    script.write_text(
        f"#!{sys.executable}\n"
        "import os\n"
        "n = int(os.environ['BENCH_REPS'])\n"
        "x = 0\n"
        "for i in range(n * 200000):\n"
        "    x += i\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    ms = bench.per_call_ms(str(script), "", "bwd", "sphere", 6)
    assert 0.0 < ms < 1000.0
