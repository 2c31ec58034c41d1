"""The ``meshadv`` command's allocator policy (meshadv.allocator), checked in fresh processes."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from meshadv import allocator

_PROBE = "from meshadv.allocator import tune_allocator; print(tune_allocator())"


def _probe(env_value: str | None) -> str:
    env = dict(os.environ)
    env.pop(allocator.TUNING_ENV_VAR, None)
    if env_value is not None:
        env[allocator.TUNING_ENV_VAR] = env_value
    return subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_tuning_applies_on_glibc_and_can_be_turned_off() -> None:
    assert _probe(None) == "True"
    assert _probe("0") == "False"


def test_cli_applies_the_policy_before_running_a_command(monkeypatch: pytest.MonkeyPatch) -> None:
    from meshadv import cli

    calls: list[str] = []
    monkeypatch.setattr(cli, "tune_allocator", lambda: calls.append("tuned") or True)
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--help"])
    assert exit_info.value.code == 0 and calls == ["tuned"]
