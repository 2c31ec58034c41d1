"""Pipelined attack steps (meshadv.attacks.pipeline): the same gradients as the one-thread step, exceptions and
Ctrl-C in workers, thread settings, and the chunk helpers."""

from __future__ import annotations

import threading
from typing import Any, List

import pytest
import torch

from meshadv.render import RenderSetup, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _views(num: int) -> Any:
    from meshadv.render import ViewSet

    return ViewSet.orbit([40.0 + 35.0 * i for i in range(num)], elevation=20.0, distance=2.6)


class _SumRule:
    """A rule whose objective uses every term, so that the perceptual and distance terms must backprop too; its
    renders weight the rasterization gradient ``visibility_gradient`` by ``edge_gradient``."""

    def __init__(self, weights: torch.Tensor, edge_gradient: float = 1.0, visibility_gradient: str = "nmr") -> None:
        self.weights = weights
        self.edge_gradient = edge_gradient
        self.visibility_gradient = visibility_gradient

    def objective(self, adv: torch.Tensor, perc: torch.Tensor, dist: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return (adv + self.weights[idx] * perc + 0.5 * self.weights[idx] * dist).sum()


def _call(attack: Any, mesh: Any, views: Any, victim: Any, size: int = 48) -> Any:
    from meshadv.attacks.base import _Call
    from meshadv.mesh.adjacency import vertex_edges

    return _Call(mesh, views.detach(), victim, RenderSetup(image_size=size, antialias=2),
                 vertex_edges(mesh.faces).long())


def _step_grads(attack: Any, call: Any, criteria: List[Any], workers: Any, params: torch.Tensor,
                idx: torch.Tensor, edge_gradient: float = 1.0, visibility_gradient: str = "nmr") -> Any:
    rule = _SumRule(torch.tensor([0.3, 2.0, 0.7, 1.5]), edge_gradient, visibility_gradient)
    p = params.detach().clone().requires_grad_(True)
    bound = [c.bind(call.victim) for c in criteria]
    if workers is None:
        out = attack._serial_step(p[idx], idx, bound, call, call.views, rule)
    else:
        out = attack._pipelined_step(p, idx, bound, call, call.views, rule, workers)
    return p.grad, out


@needs_native
@pytest.mark.parametrize("family", ["shape", "texture"])
@pytest.mark.parametrize("num_workers", [2, 3])
def test_pipelined_step_gradients_match_the_serial_step(family: str, num_workers: int) -> None:
    """Same parameters -> the same gradient (perceptual and distance terms included), losses and margins, with
    chunks of uneven size and a subset of active targets."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    victim = PooledLinearClassifier()
    attack = ShapeAttack() if family == "shape" else TextureAttack()
    call = _call(attack, mesh, _views(2), victim)
    gen = torch.Generator().manual_seed(1)
    params = attack._init_params(mesh, 4) + 0.02 * torch.randn(attack._init_params(mesh, 4).shape, generator=gen)
    idx = torch.tensor([0, 1, 3])
    criteria = [TargetedMisclassification(c) for c in (728, 247, 5, 400)]
    criteria = [criteria[i] for i in idx.tolist()]
    g_serial, (adv_s, perc_s, dist_s, out_s, marg_s) = _step_grads(attack, call, criteria, None, params, idx)
    with StepWorkers(num_workers, 1) as workers:
        g_pipe, (adv_p, perc_p, dist_p, out_p, marg_p) = _step_grads(attack, call, criteria, workers, params, idx)
    assert g_serial is not None and g_pipe is not None
    assert float(g_serial[idx].abs().max()) > 0
    assert torch.equal(g_pipe[2], torch.zeros_like(g_pipe[2]))  # the inactive target's rows
    # the victim at another batch size rounds differently: ~1e-7 of the largest entry measured
    torch.testing.assert_close(g_pipe, g_serial, rtol=1e-5, atol=1e-6 * float(g_serial.abs().max()))
    for a, b in ((adv_p, adv_s), (perc_p, perc_s), (dist_p, dist_s), (out_p, out_s), (marg_p, marg_s)):
        torch.testing.assert_close(a.detach(), b.detach(), rtol=1e-5, atol=1e-5)  # logits: batch-size rounding


@needs_native
def test_the_rules_edge_gradient_weights_the_rasterization_part_of_every_step() -> None:
    """A rule's ``edge_gradient`` reaches the renders of the serial and the pipelined step: the shape gradient is
    the shading part plus ``w`` times the rasterization part (linear in ``w``), the same in both steps."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(attack, mesh, _views(2), PooledLinearClassifier())
    params = 0.02 * torch.randn(attack._init_params(mesh, 2).shape, generator=torch.Generator().manual_seed(2))
    idx = torch.tensor([0, 1])
    criteria = [TargetedMisclassification(c) for c in (728, 247)]
    serial = {w: _step_grads(attack, call, criteria, None, params, idx, w)[0] for w in (0.0, 0.25, 1.0)}
    assert float((serial[1.0] - serial[0.0]).abs().max()) > 0.1 * float(serial[1.0].abs().max())
    torch.testing.assert_close(serial[0.25], 0.75 * serial[0.0] + 0.25 * serial[1.0],
                               rtol=1e-4, atol=1e-5 * float(serial[1.0].abs().max()))
    with StepWorkers(2, 1) as workers:
        piped = _step_grads(attack, call, criteria, workers, params, idx, 0.25)[0]
    torch.testing.assert_close(piped, serial[0.25], rtol=1e-5, atol=1e-6 * float(serial[0.25].abs().max()))


@needs_native
def test_the_rules_visibility_gradient_reaches_the_renders_of_every_step() -> None:
    """A rule's ``visibility_gradient`` reaches the renders of the serial and the pipelined step: the local one
    changes the shape gradient, and both steps agree on it."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(attack, mesh, _views(2), PooledLinearClassifier())
    params = 0.02 * torch.randn(attack._init_params(mesh, 2).shape, generator=torch.Generator().manual_seed(2))
    idx = torch.tensor([0, 1])
    criteria = [TargetedMisclassification(c) for c in (728, 247)]
    nmr = _step_grads(attack, call, criteria, None, params, idx)[0]
    local = _step_grads(attack, call, criteria, None, params, idx, visibility_gradient="local")[0]
    assert float((nmr - local).abs().max()) > 1e-3 * float(nmr.abs().max())
    with StepWorkers(2, 1) as workers:
        piped = _step_grads(attack, call, criteria, workers, params, idx, visibility_gradient="local")[0]
    torch.testing.assert_close(piped, local, rtol=1e-5, atol=1e-6 * float(local.abs().max()))


@needs_native
def test_pipelined_step_gradients_reach_the_perceptual_image_term() -> None:
    """Texture's perceptual term is a function of the images: without the victim's term its gradient must still come
    through the render (a zero-weight adversarial term isolates it)."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import TargetedMisclassification, TextureAttack
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    class PercOnly:
        edge_gradient = 1.0
        visibility_gradient = "nmr"

        def objective(self, adv: torch.Tensor, perc: torch.Tensor, dist: torch.Tensor,
                      idx: torch.Tensor) -> torch.Tensor:
            return 0.0 * adv.sum() + perc.sum()

    mesh = builtin_mesh("sofa")
    attack = TextureAttack()
    call = _call(attack, mesh, _views(1), PooledLinearClassifier())
    params = attack._init_params(mesh, 2) + 0.1 * torch.randn(attack._init_params(mesh, 2).shape,
                                                             generator=torch.Generator().manual_seed(3))
    idx = torch.tensor([0, 1])
    crits = [TargetedMisclassification(c).bind(call.victim) for c in (1, 2)]
    grads = []
    for workers in (None, StepWorkers(2, 1)):
        p = params.clone().requires_grad_(True)
        if workers is None:
            attack._serial_step(p[idx], idx, crits, call, call.views, PercOnly())
        else:
            attack._pipelined_step(p, idx, crits, call, call.views, PercOnly(), workers)
            workers.close()
        grads.append(p.grad)
    assert float(grads[0].abs().max()) > 0
    torch.testing.assert_close(grads[1], grads[0], rtol=1e-5, atol=1e-9)


@needs_native
@pytest.mark.parametrize("family", ["shape", "texture"])
def test_attack_with_step_workers_matches_one_worker(family: str) -> None:
    """A short attack with 2 step workers (targets finishing at different steps) follows the 1-worker run. Both run
    torch on one thread per worker: with 2 threads the 1-worker run's victim reduces in another order than the
    workers' one-thread victims, which Adam's shape steps amplified to 1.4e-3 of a loss within 5 steps on an Intel
    AVX-512 machine."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack
    from meshadv.mesh import builtin_mesh

    victim = PooledLinearClassifier()
    mesh = builtin_mesh("chair")
    crits = [TargetedMisclassification(c) for c in (728, 247, 5)]
    results = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for workers in (1, 2):
            if family == "shape":
                attack = ShapeAttack(steps=5, lr=3e-2, lambda_perceptual=0.01, step_workers=workers)
            else:
                attack = TextureAttack(steps=5, lr=0.2, early_stop=1, step_workers=workers)
            results.append(attack(mesh, _views(2), victim, crits, setup=RenderSetup(image_size=48, antialias=2)))
    finally:
        torch.set_num_threads(threads)
    one, two = results
    assert one.steps == two.steps
    assert one.success.tolist() == two.success.tolist()
    for a, b in zip(one.distances, two.distances):
        for key in ("laplacian_sum", "color_rmse", "max_displacement"):
            assert b[key] == pytest.approx(a[key], rel=1e-3, abs=1e-9)
    for row_a, row_b in zip(one.loss_history, two.loss_history):
        for x, y in zip(row_a["loss"], row_b["loss"]):
            assert (x is None) == (y is None)
            if x is not None:
                assert y == pytest.approx(x, rel=1e-4, abs=1e-6)


class _Boom(Exception):
    pass


@needs_native
def test_worker_exception_is_raised_in_the_caller() -> None:
    """A victim that fails inside a worker fails the attack call with its own exception."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh import builtin_mesh

    class Failing(PooledLinearClassifier):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            if torch.is_grad_enabled() and threading.current_thread() is not threading.main_thread():
                raise _Boom("victim failed in a worker")
            return super().forward(images)

    attack = ShapeAttack(steps=3, step_workers=2)
    with pytest.raises(_Boom, match="in a worker"):
        attack(builtin_mesh("chair"), _views(1), Failing(), [TargetedMisclassification(1),
                                                             TargetedMisclassification(2)],
               setup=RenderSetup(image_size=32))


@needs_native
def test_keyboard_interrupt_in_a_worker_stops_the_attack_cleanly() -> None:
    """Ctrl-C raised while the workers run a step stops the attack between steps with ``interrupted=True``."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh import builtin_mesh

    calls = {"n": 0}

    class Interrupting(PooledLinearClassifier):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            if torch.is_grad_enabled() and threading.current_thread() is not threading.main_thread():
                calls["n"] += 1
                if calls["n"] > 4:  # third step: 2 chunks per step
                    raise KeyboardInterrupt
            return super().forward(images)

    attack = ShapeAttack(steps=10, step_workers=2)
    result = attack(builtin_mesh("chair"), _views(1), Interrupting(),
                    [TargetedMisclassification(1), TargetedMisclassification(2)], setup=RenderSetup(image_size=32))
    assert result.interrupted
    assert result.steps == 2


def test_step_workers_threads_and_restore() -> None:
    """Each worker runs torch on its own thread count; the caller's count and the process default are restored."""
    from meshadv.attacks.pipeline import StepWorkers

    before = torch.get_num_threads()
    with StepWorkers(2, 1) as workers:
        seen = workers.map(lambda _: (torch.get_num_threads(), threading.current_thread().name), range(4))
        assert torch.get_num_threads() == before
    assert all(n == 1 for n, _ in seen)
    assert all(name.startswith("meshadv-step") for _, name in seen)
    fresh: List[int] = []
    thread = threading.Thread(target=lambda: fresh.append(torch.get_num_threads()))
    thread.start()
    thread.join()
    assert fresh == [before]
    with pytest.raises(RuntimeError, match="closed"):
        workers.map(abs, [1])


def test_step_workers_map_waits_for_every_task_and_raises_the_first_error() -> None:
    """All tasks finish before the first failure (in item order) is raised."""
    import time

    from meshadv.attacks.pipeline import StepWorkers

    done: List[int] = []

    def task(i: int) -> int:
        if i == 1:
            raise ValueError("task 1")
        time.sleep(0.05)
        done.append(i)
        return i

    with StepWorkers(2, 1) as workers:
        with pytest.raises(ValueError, match="task 1"):
            workers.map(task, [0, 1, 2])
        assert sorted(done) == [0, 2]
        assert workers.map(lambda i: i * i, [3, 1, 2]) == [9, 1, 4]


def test_split_chunks() -> None:
    from meshadv.attacks.pipeline import split_chunks

    assert split_chunks(6, 2) == [(0, 3), (3, 6)]
    assert split_chunks(5, 2) == [(0, 3), (3, 5)]
    assert split_chunks(3, 4) == [(0, 1), (1, 2), (2, 3)]
    assert split_chunks(0, 2) == []
    for n in range(1, 12):
        for k in range(1, 5):
            chunks = split_chunks(n, k)
            assert chunks[0][0] == 0 and chunks[-1][1] == n
            assert all(a[1] == b[0] for a, b in zip(chunks, chunks[1:]))
            sizes = [b - a for a, b in chunks]
            assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1
    with pytest.raises(ValueError, match="parts"):
        split_chunks(3, 0)


def test_cat_outputs_detector() -> None:
    from meshadv.attacks.pipeline import cat_outputs, output_tensors
    from meshadv.victims.base import DetectorOutput

    a = DetectorOutput(boxes=torch.rand(2, 5, 4), objectness=None, class_probs=torch.rand(2, 5, 3))
    b = DetectorOutput(boxes=torch.rand(1, 5, 4), objectness=None, class_probs=torch.rand(1, 5, 3))
    c = cat_outputs([a, b])
    assert isinstance(c, DetectorOutput) and c.objectness is None
    assert torch.equal(c.boxes, torch.cat([a.boxes, b.boxes]))
    assert torch.equal(cat_outputs([torch.ones(1, 2), torch.zeros(2, 2)]), torch.tensor([[1.0, 1], [0, 0], [0, 0]]))
    with pytest.raises(TypeError, match="victim output"):
        output_tensors([1, 2])


@pytest.mark.parametrize("bad, exc", [(0, ValueError), (1.5, TypeError), ("2", TypeError), (10**6, ValueError)])
def test_step_workers_validation(bad: Any, exc: type) -> None:
    from meshadv.attacks import ShapeAttack

    with pytest.raises(exc, match="step_workers"):
        ShapeAttack(step_workers=bad)


@needs_native
def test_pipelined_step_splits_the_targets_over_the_workers() -> None:
    """3 active targets x 2 views over 2 workers: the victim sees chunks of 2 and 1 targets, in worker threads."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    seen: List[Any] = []

    class Recording(PooledLinearClassifier):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            seen.append((images.shape[0], threading.current_thread().name))
            return super().forward(images)

    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(attack, mesh, _views(2), Recording())
    crits = [TargetedMisclassification(c) for c in (1, 2, 3)]
    with StepWorkers(2, 1) as workers:
        _step_grads(attack, call, crits, workers, attack._init_params(mesh, 4), torch.tensor([0, 1, 3]))
    assert sorted(n for n, _ in seen) == [2, 4]
    assert all(name.startswith("meshadv-step") for _, name in seen)


@needs_native
@pytest.mark.parametrize("threads", [1, 2])
def test_workers_render_on_thread_pools_of_their_own(threads: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each worker renders with its thread count (a pool of the calling thread's own in the native module), the
    serial step on rayon's global pool (0); the images are the same bits whatever the count."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh
    from meshadv.render import renderer

    calls: List[Any] = []
    real = renderer._render_rgba

    def recording(*args: Any, **kwargs: Any) -> Any:
        calls.append((kwargs["num_threads"], threading.current_thread().name))
        return real(*args, **kwargs)

    monkeypatch.setattr(renderer, "_render_rgba", recording)
    mesh = builtin_mesh("chair")
    attack = ShapeAttack()
    call = _call(attack, mesh, _views(2), PooledLinearClassifier())
    crits = [TargetedMisclassification(c) for c in (1, 2, 3)]
    params, idx = attack._init_params(mesh, 4), torch.tensor([0, 1, 3])
    _step_grads(attack, call, crits, None, params, idx)
    assert calls == [(0, threading.current_thread().name)]
    calls.clear()
    with StepWorkers(2, threads) as workers:
        _step_grads(attack, call, crits, workers, params, idx)
    assert len(calls) == 2
    assert all(n == threads and name.startswith("meshadv-step") for n, name in calls)
    verts = mesh.vertices.unsqueeze(0).repeat(2, 1, 1)
    one, _ = call.setup.render(verts, mesh.faces, mesh.face_colors, call.views, num_threads=threads)
    pooled, _ = call.setup.render(verts, mesh.faces, mesh.face_colors, call.views)
    assert torch.equal(one, pooled)


@needs_native
def test_detector_attack_with_step_workers_matches_one_worker() -> None:
    """The detector's output (boxes, no objectness, class probabilities) is cut and concatenated like logits."""
    from stand_in_victims import DarkBlobDetector

    from meshadv.attacks import Disappearance, TextureAttack
    from meshadv.mesh import builtin_mesh

    cube = builtin_mesh("cube", color=(0.1, 0.1, 0.1))
    crits = [Disappearance("blob"), Disappearance("blob", threshold=0.3)]
    runs = [TextureAttack(steps=4, lr=0.2, step_workers=w)(cube, _views(2), DarkBlobDetector(), crits,
                                                           setup=RenderSetup(image_size=32))
            for w in (1, 2)]
    assert runs[0].steps == runs[1].steps == 4
    assert runs[0].success.tolist() == runs[1].success.tolist()
    for row_a, row_b in zip(runs[0].loss_history, runs[1].loss_history):
        assert row_b["loss"] == pytest.approx(row_a["loss"], rel=1e-5, abs=1e-7)
    assert runs[1].loss_history[-1]["loss"] != runs[1].loss_history[0]["loss"]


def test_ctrl_c_in_the_caller_waits_for_the_running_tasks() -> None:
    """SIGINT while the calling thread waits on the workers: KeyboardInterrupt propagates only once the tasks that had
    started are done (no worker is left writing gradients into a step that was abandoned)."""
    import os
    import signal
    import time

    from meshadv.attacks.pipeline import StepWorkers

    done: List[int] = []
    started = threading.Barrier(2)
    interrupted = threading.Event()

    def on_sigint(signum: int, frame: object) -> None:
        interrupted.set()
        raise KeyboardInterrupt

    def task(i: int) -> int:
        started.wait(timeout=10)  # both tasks are running before the signal
        if i == 0:
            os.kill(os.getpid(), signal.SIGINT)
        assert interrupted.wait(timeout=10), "the calling thread never handled SIGINT"
        time.sleep(0.05)  # still running after the caller saw the interrupt
        done.append(i)
        return i

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        with StepWorkers(2, 1) as workers:
            with pytest.raises(KeyboardInterrupt):
                workers.map(task, [0, 1])
            assert sorted(done) == [0, 1]
            assert workers.map(lambda i: i + 1, [1]) == [2]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_split_images() -> None:
    from meshadv.attacks.pipeline import split_images

    assert split_images(6, 1, 2) == [[(0, 3, 0, 1)], [(3, 6, 0, 1)]]
    assert split_images(1, 5, 2) == [[(0, 1, 0, 3)], [(0, 1, 3, 5)]]
    assert split_images(3, 2, 4) == [[(0, 1, 0, 2)], [(1, 2, 0, 2)], [(2, 3, 0, 1)], [(2, 3, 1, 2)]]
    assert split_images(3, 5, 2) == [[(0, 2, 0, 5)], [(2, 3, 0, 5)]]  # whole targets when there are enough
    assert split_images(2, 5, 3) == [[(0, 1, 0, 4)], [(0, 1, 4, 5), (1, 2, 0, 2)], [(1, 2, 2, 5)]]
    for k in range(1, 5):
        for v in range(1, 5):
            for w in range(1, 6):
                images = [(t, view) for blocks in split_images(k, v, w) for k0, k1, v0, v1 in blocks
                          for t in range(k0, k1) for view in range(v0, v1)]
                assert images == [(t, view) for t in range(k) for view in range(v)]  # mesh-major, each once
    with pytest.raises(ValueError, match="counts"):
        split_images(0, 1, 1)


@needs_native
@pytest.mark.parametrize("family", ["shape", "texture"])
@pytest.mark.parametrize("num_targets, num_views, num_workers", [(1, 3, 2), (3, 2, 4), (2, 3, 3)])
def test_pipelined_step_split_by_views_matches_the_serial_step(family: str, num_targets: int, num_views: int,
                                                             num_workers: int) -> None:
    """Chunks that split one target's views (its rows summed over chunks) give the serial step's gradient."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack
    from meshadv.attacks.pipeline import StepWorkers
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    attack = ShapeAttack() if family == "shape" else TextureAttack()
    call = _call(attack, mesh, _views(num_views), PooledLinearClassifier())
    shape = attack._init_params(mesh, 4).shape
    params = attack._init_params(mesh, 4) + 0.02 * torch.randn(shape, generator=torch.Generator().manual_seed(5))
    idx = torch.tensor([3, 0, 2][:num_targets])
    crits = [TargetedMisclassification(c) for c in (728, 247, 5)][:num_targets]
    g_serial, out_s = _step_grads(attack, call, crits, None, params, idx)
    with StepWorkers(num_workers, 1) as workers:
        g_pipe, out_p = _step_grads(attack, call, crits, workers, params, idx)
    assert float(g_serial.abs().max()) > 0
    torch.testing.assert_close(g_pipe, g_serial, rtol=1e-5, atol=1e-6 * float(g_serial.abs().max()))
    for a, b in zip(out_p, out_s):
        torch.testing.assert_close(a.detach(), b.detach(), rtol=1e-5, atol=1e-5)


@needs_native
def test_single_target_attack_is_split_by_views() -> None:
    """One target seen from 3 views with 2 workers: the victim sees chunks of 2 and 1 views, and the run follows the
    1-worker run."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.mesh import builtin_mesh

    sizes: List[int] = []

    class Recording(PooledLinearClassifier):
        def forward(self, images: torch.Tensor) -> torch.Tensor:
            if torch.is_grad_enabled():
                sizes.append(images.shape[0])
            return super().forward(images)

    runs = []
    for workers in (1, 2):
        sizes.clear()
        attack = ShapeAttack(steps=3, lr=3e-2, lambda_perceptual=0.01, step_workers=workers)
        runs.append(attack(builtin_mesh("chair"), _views(3), Recording(), TargetedMisclassification(728),
                           setup=RenderSetup(image_size=48, antialias=2)))
        assert sorted(set(sizes)) == ([3] if workers == 1 else [1, 2])
    for row_a, row_b in zip(runs[0].loss_history, runs[1].loss_history):
        assert row_b["loss"][0] == pytest.approx(row_a["loss"][0], rel=1e-4, abs=1e-6)
