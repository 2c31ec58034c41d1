"""What ran: the versions of Python, the platform and the main packages, the git state of the checkout, and the CPU
and kernels that decide an attack's float rounding."""

from __future__ import annotations

import platform
import sys
from pathlib import Path
from typing import Dict

__all__ = ["compute_environment", "environment_versions"]


def _git_state(folder: Path) -> Dict[str, str]:
    """``{"git_commit": ..., "git_dirty": "yes"/"no"}`` of the checkout holding ``folder`` (``{}`` outside one): the
    package version alone does not say which code ran, and an editable install runs uncommitted edits too."""
    import subprocess

    try:
        commit = subprocess.run(["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        status = subprocess.run(["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no", "--",
                                 "."], capture_output=True, text=True, timeout=10, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_commit": commit, "git_dirty": "yes" if status.strip() else "no"} if commit else {}


def environment_versions() -> Dict[str, str]:
    """Versions of Python, the platform and the main packages (those importable), and, when meshadv runs from a git
    checkout, its commit and whether the package's files had uncommitted changes (``git_dirty``)."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in ("meshadv", "torch", "numpy", "matplotlib", "ray"):
        try:
            module = __import__(name)
            out[name] = str(getattr(module, "__version__", "?"))
        except Exception:  # noqa: BLE001 - a missing optional package is simply not listed
            continue
    try:
        import meshadv

        out.update(_git_state(Path(meshadv.__file__).resolve().parent))
    except Exception:  # noqa: BLE001 - versions are informative, never fatal
        pass
    return out


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def compute_environment() -> Dict[str, str]:
    """What an attack's float rounding depends on besides its code and inputs: the CPU model, the instruction set
    torch's CPU kernels use (``torch.backends.cpu.get_cpu_capability()``: AVX2, AVX512, ...; ``ATEN_CPU_CAPABILITY``
    lowers it) and torch's thread count. An attack is a chaotic trajectory, so a job reruns bit for bit only where
    these match (docs/guide/sweeps.md, "Resuming and stopping"); each job record keeps them."""
    out = {"cpu": _cpu_model()}
    try:
        import torch

        out["torch_cpu_capability"] = str(torch.backends.cpu.get_cpu_capability())
        out["torch_threads"] = str(torch.get_num_threads())
    except Exception:  # noqa: BLE001 - informative, never fatal
        pass
    return out
