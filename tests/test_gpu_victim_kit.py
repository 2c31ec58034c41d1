"""benchmarks/gpu_victim_kit.py (the GPU-victim benchmark's one-call device kit) and attack_bench's ``--device``."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from benchmark_scripts import load_benchmark

kit = load_benchmark("gpu_victim_kit")
attack_bench = load_benchmark("attack_bench")


def test_the_carried_requirements_are_pinned_in_requirements_txt() -> None:
    pins = kit.pinned_versions(kit.REPO / "requirements.txt", kit.CARRIED)
    assert set(pins) == set(kit.CARRIED)
    assert all(v[0].isdigit() for v in pins.values())


def test_an_unpinned_requirement_is_named(tmp_path: Path) -> None:
    req = tmp_path / "requirements.txt"
    req.write_text("# comment\nTrimesh==5.2.0\nnumpy>=2\n")
    assert kit.pinned_versions(req, ["trimesh"]) == {"trimesh": "5.2.0"}
    with pytest.raises(ValueError, match="numpy"):
        kit.pinned_versions(req, ["trimesh", "numpy"])


def test_travelling_bytes_counts_tracked_untracked_and_carried_files_but_not_ignored_ones(tmp_path: Path) -> None:
    git = shutil.which("git")
    if git is None:
        pytest.skip("git is not installed")
    repo = tmp_path / "repo"
    repo.mkdir()
    subprocess.run([git, "init", "-q"], cwd=repo, check=True)
    (repo / ".gitignore").write_text("ignored/\n")  # 9 bytes, untracked
    (repo / "tracked.txt").write_text("x" * 10)
    subprocess.run([git, "add", "tracked.txt"], cwd=repo, check=True)
    (repo / "untracked.txt").write_text("y" * 5)
    (repo / "ignored").mkdir()
    (repo / "ignored" / "big.bin").write_bytes(b"z" * 100)
    (repo / "ignored" / "carried.bin").write_bytes(b"c" * 7)
    assert kit.travelling_bytes(repo, []) == 9 + 10 + 5
    assert kit.travelling_bytes(repo, [repo / "ignored" / "carried.bin"]) == 9 + 10 + 5 + 7
    assert kit.travelling_bytes(repo, [repo / "ignored"]) == 9 + 10 + 5 + 107


def test_quick_arguments_shrink_every_size_and_fill_the_placeholders() -> None:
    for _, template, _ in kit.RUNS:
        args = kit._arguments(template, "cuda", 16, quick=True)
        assert "{device}" not in " ".join(args) and "{threads}" not in " ".join(args)
        assert args[args.index("--image-size") + 1] == "64"
        assert args[args.index("--targets") + 1] == "2"
        if "--whole-steps" in args:
            assert args[args.index("--torch-threads") + 1] == "16"
    full = kit._arguments(kit.RUNS[0][1], "cuda:1", 16, quick=False)
    assert full[full.index("--device") + 1] == "cuda:1" and full[full.index("--image-size") + 1] == "224"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--split", "--cpu-time", "--device", "cuda"], "--cpu-time"),
        (["--split", "--device", "no-such-device"], "not a torch device"),
    ],
)
def test_attack_bench_refuses_a_device_it_cannot_time_naming_the_option(
    argv: list[str], message: str, capsys: pytest.CaptureFixture
) -> None:
    with pytest.raises(SystemExit) as exc:
        attack_bench.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_the_kit_runs_its_benchmarks_on_the_cpu(
    shared_data: Path, lite0_victim: object, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The device path end to end on this machine (victim on the CPU, small sizes), with the kit's own data folder
    # (the device machine has no shared data) and two of its runs: a step split and the whole steps.
    for mesh in kit.MESHES:
        source = shared_data / mesh
        if not source.is_file():
            pytest.skip(f"shared mesh {source} is missing")
        (tmp_path / "kit" / "data" / mesh).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, tmp_path / "kit" / "data" / mesh)
    monkeypatch.setattr(kit, "RUNS", tuple(r for r in kit.RUNS if r[0] in ("split_1view", "whole_steps")))
    out = tmp_path / "out"
    assert kit.run(tmp_path / "kit", out, "cpu", quick=True) == 0
    machine = json.loads((out / "machine.json").read_text())
    assert machine["cpus"] >= 1 and machine["torch"]
    split = json.loads((out / "split_1view.json").read_text())["records"]
    assert [r["perturb"] for r in split] == ["shape"] and split[0]["device"] == "cpu"
    assert split[0]["render_bwd_s"] > 0 and split[0]["victim_s"] > 0
    whole = json.loads((out / "whole_steps.json").read_text())["records"][0]
    assert any(k.startswith("serial t") for k in whole["step_s"])
    assert whole["device"] == "cpu"
    log = (out / "log.txt").read_text()
    assert "## split_1view" in log and "## whole_steps" in log and "failed" not in log
