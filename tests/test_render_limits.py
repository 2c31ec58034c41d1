"""Resource limits of the render ops: memory is estimated before allocating, thread pools are bounded."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import time

import pytest
import torch

from meshadv.render import Camera, Lights, render
from meshadv.render._memory import check_memory, estimate_forward_bytes
from meshadv.render.rasterize import rasterize


def tetrahedron() -> tuple[torch.Tensor, torch.Tensor]:
    """A small closed mesh around the origin."""
    verts = torch.tensor([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]) * 0.5
    return verts, torch.tensor([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])


def test_memory_estimate_counts_every_per_pixel_buffer() -> None:
    # 16384^2 pixels with 4 channels: 16 + 8*4 bytes per pixel.
    assert estimate_forward_bytes(1, 16384, 16384, 4, 0, 0) == 16384 * 16384 * 48
    with pytest.raises(MemoryError, match=r"render needs about 1024\.00 GiB"):
        check_memory(2**40, "render")


def test_background_of_the_wrong_type_is_a_type_error() -> None:
    verts, faces = tetrahedron()
    colors = torch.full((faces.shape[0], 3), 0.5)
    for bad in ("white", None):
        with pytest.raises(TypeError, match="^background must be"):
            render(verts, faces, colors, Camera.spherical(3.0), Lights.default(), 8, background=bad)


def test_huge_render_under_an_address_space_limit_raises_memory_error_not_abort() -> None:
    code = textwrap.dedent(
        """
        import resource, torch
        from meshadv.render import Camera, Lights, render
        from meshadv.render._memory import _vm_size_bytes
        verts = torch.tensor([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]) * 0.5
        faces = torch.tensor([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
        colors = torch.full((faces.shape[0], 3), 0.5)
        used = _vm_size_bytes()
        resource.setrlimit(resource.RLIMIT_AS, (used + 2**30, resource.RLIM_INFINITY))
        try:
            render(verts, faces, colors, Camera.spherical(3.0), Lights.default(), 16384)
        except MemoryError as exc:
            print("MemoryError:", exc)
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "MemoryError: rasterize needs about 12.00 GiB" in done.stdout


def _threads_of_this_process() -> int:
    return len(os.listdir("/proc/self/task"))


def _render_a_triangle(num_threads: int = 0) -> None:
    """Rasterize one screen-space triangle at 8 px on ``num_threads`` threads (0: the global pool)."""
    verts = torch.tensor([[[-0.9, -0.9, 1.0], [0.9, -0.9, 1.0], [0.0, 0.9, 1.0]]])
    rasterize(verts, torch.tensor([[0, 2, 1]]), torch.ones(1, 1, 1), 8, num_threads=num_threads)


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through Linux /proc")
def test_distinct_thread_counts_do_not_accumulate_threads() -> None:
    import meshadv._raster as native

    # a stale extension fails here instead of skipping the check: rebuild it (maturin develop --release)
    assert hasattr(native, "MAX_CACHED_POOLS"), "the native module predates the bounded pool cache"
    kept = native.MAX_CACHED_POOLS
    assert kept >= 1
    _render_a_triangle()
    before = _threads_of_this_process()
    for n in range(1, 65):
        _render_a_triangle(n)
    # Only the `kept` most recently used pools survive (64 + 63 threads for 2), not one pool per value asked for.
    bound = before + sum(range(65 - kept, 65)) + 4
    for _ in range(100):  # evicted pools' threads exit asynchronously
        if _threads_of_this_process() <= bound:
            break
        time.sleep(0.05)
    assert _threads_of_this_process() <= bound


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through Linux /proc")
def test_a_threads_explicit_pools_are_its_own_and_exit_with_it() -> None:
    """Threads rendering with an explicit count at the same time each get a pool of their own (its threads come on
    top of the callers'), and a pool's threads exit when the thread that made it exits."""
    _render_a_triangle()
    before = _threads_of_this_process()
    rendered, release = threading.Barrier(3), threading.Event()

    def caller() -> None:
        _render_a_triangle(3)
        rendered.wait()
        release.wait()

    callers = [threading.Thread(target=caller) for _ in range(2)]
    for t in callers:
        t.start()
    rendered.wait()  # both have rendered and are alive
    during = _threads_of_this_process()
    release.set()
    for t in callers:
        t.join()
    # two callers + a pool of 3 each (one shared pool would leave 2 + 3)
    assert during >= before + 2 + 2 * 3
    for _ in range(100):  # the pools' threads exit asynchronously once their caller has gone
        if _threads_of_this_process() <= before:
            break
        time.sleep(0.05)
    assert _threads_of_this_process() <= before
