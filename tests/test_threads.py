"""The thread policy (meshadv.threads), `--threads` on every command, and what is deterministic across counts."""

from __future__ import annotations

import os
import subprocess
import sys
from typing import Iterator

import pytest
import torch
from typer.testing import CliRunner

from meshadv import threads
from meshadv.cli import app


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """No thread or wait-policy variables; torch's thread count restored afterwards."""
    for var in (*threads.THREAD_COUNT_VARS, *threads.WAIT_POLICY_VARS, threads.THREADS_ENV_VAR):
        monkeypatch.delenv(var, raising=False)
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_prepare_environment_sets_passive_wait_and_keeps_the_users_choice(
    clean_env: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("KMP_BLOCKTIME", "7")
    count = threads.prepare_environment()
    assert count == threads.available_cpus()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert os.environ["KMP_BLOCKTIME"] == "7"  # the user's value wins
    assert os.environ["RAYON_NUM_THREADS"] == str(count)
    assert threads.prepare_environment(1) == 1  # an explicit count overrides
    assert all(os.environ[v] == "1" for v in threads.THREAD_COUNT_VARS)


def test_apply_threads_sizes_torch_and_reads_meshadv_threads(clean_env: None,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    assert threads.apply_threads(1) == 1
    assert torch.get_num_threads() == 1
    monkeypatch.delenv("OMP_NUM_THREADS")
    monkeypatch.setenv(threads.THREADS_ENV_VAR, "2")
    assert threads.default_threads() == 2
    assert threads.apply_threads() == 2 and torch.get_num_threads() == 2


@pytest.mark.parametrize("bad, error", [(0, ValueError), (-1, ValueError), (2000, ValueError), (1.5, TypeError),
                                        (True, TypeError), ("2", TypeError)])
def test_bad_thread_counts_are_refused(clean_env: None, bad: object, error: type) -> None:
    with pytest.raises(error, match="threads"):
        threads.apply_threads(bad)  # type: ignore[arg-type]


def test_bad_meshadv_threads_is_refused(clean_env: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(threads.THREADS_ENV_VAR, "many")
    with pytest.raises(ValueError, match="MESHADV_THREADS"):
        threads.default_threads()


def test_cli_sets_the_wait_policy_before_torch_loads() -> None:
    code = ("import os, sys; from meshadv.cli import main\n"
            "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["PASSIVE", "False"]


def test_every_command_has_threads() -> None:
    runner = CliRunner()
    from meshadv.cli import SUBCOMMANDS  # noqa: F401  (the app is built from it)

    def commands(group: object, prefix: list) -> Iterator[list]:
        import typer.main

        click_group = typer.main.get_command(group) if not hasattr(group, "commands") else group
        for name, cmd in click_group.commands.items():
            if hasattr(cmd, "commands"):
                yield from commands(cmd, prefix + [name])
            else:
                yield prefix + [name]

    names = list(commands(app, []))
    assert ["demo"] in names and ["transfer", "check"] in names
    for name in names:
        result = runner.invoke(app, [*name, "--help"], terminal_width=200)
        assert result.exit_code == 0, (name, result.output)
        assert "--threads" in result.output, name


def test_threads_option_applies_and_validates(clean_env: None, tmp_path: os.PathLike) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["render", "builtin:sphere", "--views", "1", "--image-size", "16", "--threads", "0",
                                 "-o", str(tmp_path)])
    assert result.exit_code == 2 and "threads" in result.output
    result = runner.invoke(app, ["render", "builtin:sphere", "--views", "1", "--image-size", "16", "--threads", "1",
                                 "-o", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert torch.get_num_threads() == 1


def test_renders_are_identical_for_any_thread_count() -> None:
    from meshadv.mesh.shapes import builtin_mesh
    from meshadv.render import Camera, Lights, render

    mesh = builtin_mesh("chair")
    camera = Camera.spherical(4.5, [150.0, 200.0], 15.0)
    verts = mesh.vertices.clone().requires_grad_(True)
    outs = []
    for n in (1, 2, 3):
        verts.grad = None
        out = render(verts, mesh.faces, mesh.face_colors, camera, Lights.default(camera), image_size=64,
                     num_threads=n)
        (out.image * torch.linspace(0, 1, out.image.numel()).view_as(out.image)).sum().backward()
        outs.append((out.image.detach(), verts.grad.clone()))
    for image, grad in outs[1:]:
        assert torch.equal(image, outs[0][0]) and torch.equal(grad, outs[0][1])


def test_same_seed_and_threads_reproduce_an_attack(clean_env: None) -> None:
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh.shapes import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet

    mesh = builtin_mesh("chair")
    views = ViewSet.orbit([170.0, 190.0], elevation=15.0, distance=4.5)
    victim = PooledLinearClassifier()
    runs = []
    for _ in range(2):
        threads.apply_threads(1)
        attack = ShapeAttack(steps=3, lr=5e-3, seed=3, early_stop=None)
        runs.append(attack(mesh, views, victim, [TargetedMisclassification(7)], setup=RenderSetup(image_size=32)))
    assert torch.equal(runs[0].adversarial[0].vertices, runs[1].adversarial[0].vertices)
    assert not torch.equal(runs[0].adversarial[0].vertices, mesh.vertices)
