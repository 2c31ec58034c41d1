"""Render :class:`~meshadv.transfer.mitsuba_spec.SceneSpec` objects with Mitsuba 3 in an isolated child process, with
the best Mitsuba variant that works on this machine.

Mitsuba can abort the whole process (e.g. ``llvm_ad_rgb`` with a too-old LLVM), so rendering never happens in the
caller's process: the specs are pickled to a child (``python -m meshadv.transfer.mitsuba_worker``), which writes the
images to a file. A crash, a non-zero exit or a timeout becomes a :class:`MitsubaRenderError` in the caller; when the
failing variant is not ``scalar_rgb`` the batch is retried once with ``scalar_rgb``.

Variants (:func:`best_variant`): ``scalar_rgb`` always works on a CPU; ``llvm_ad_rgb`` is faster (vectorised,
JIT-compiled) but needs a recent LLVM shared library, and with an old one the first render aborts the process rather
than raising. A variant is therefore probed by rendering a tiny scene in a child process (:func:`probe_variant`); the
answer is remembered for the life of the process. The environment variable ``MESHADV_MITSUBA_VARIANT`` forces a
variant (it is still probed).
"""

from __future__ import annotations

import functools
import os
import pickle
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from meshadv import _validate
from meshadv.transfer.mitsuba_spec import MitsubaCamera, SceneSpec, mask_spec

__all__ = ["FALLBACK_VARIANT", "MitsubaImage", "MitsubaRenderError", "render_mask", "render_scene", "render_scenes"]


#: Environment variable that forces a Mitsuba variant.
VARIANT_ENV_VAR = "MESHADV_MITSUBA_VARIANT"

#: Variants tried in order of preference (fastest first). ``scalar_rgb`` is the safe fallback.
PREFERRED_VARIANTS: tuple[str, ...] = ("llvm_ad_rgb", "scalar_rgb")

_PROBE_SCRIPT = """
import sys
import mitsuba as mi
mi.set_variant(sys.argv[1])
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "path", "max_depth": 2},
    "sensor": {"type": "perspective", "fov": 40,
               "film": {"type": "hdrfilm", "width": 8, "height": 8}},
    "shape": {"type": "sphere", "center": [0, 0, 4], "radius": 1.0},
    "light": {"type": "constant"},
})
image = mi.render(scene, spp=1)
assert image.shape[0] == 8
print("ok")
"""


def mitsuba_available() -> bool:
    """Whether the ``mitsuba`` package is installed (looked up with ``importlib``, without importing it)."""
    try:
        import importlib.util

        return importlib.util.find_spec("mitsuba") is not None
    except (ImportError, ValueError):
        return False


@functools.lru_cache(maxsize=None)
def probe_variant(variant: str, timeout: float = 120.0) -> bool:
    """Render a tiny scene with ``variant`` in a child process and report whether it worked.

    Args:
        variant: a Mitsuba variant name such as ``"llvm_ad_rgb"``.
        timeout: seconds before the probe is considered failed.

    Returns:
        True when the child rendered and exited cleanly; False when it failed, crashed (e.g. aborted by an old
        LLVM) or timed out.

    Raises:
        ValueError: ``variant`` is empty.
    """
    if not variant:
        raise ValueError("variant must be a non-empty Mitsuba variant name")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE_SCRIPT, variant],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0 and "ok" in proc.stdout


def best_variant(preferred: Optional[Sequence[str]] = None) -> str:
    """Return the fastest Mitsuba CPU variant that renders on this machine.

    ``$MESHADV_MITSUBA_VARIANT`` (when set) is tried first. Each candidate is probed in a child process
    (see :func:`probe_variant`), so a variant that aborts the process is skipped safely.

    Args:
        preferred: candidate variants in order of preference; default :data:`PREFERRED_VARIANTS`.

    Returns:
        The chosen variant name, e.g. ``"llvm_ad_rgb"``, or ``"scalar_rgb"`` as the fallback.

    Raises:
        ImportError: mitsuba is not installed, or none of the candidates works.

    Example:
        >>> best_variant()  # doctest: +SKIP
        'llvm_ad_rgb'
    """
    if not mitsuba_available():
        raise ImportError("mitsuba is not installed: pip install 'meshadv[transfer]' (mitsuba>=3.5)")
    candidates = list(preferred) if preferred is not None else list(PREFERRED_VARIANTS)
    forced = os.environ.get(VARIANT_ENV_VAR)
    if forced:
        candidates.insert(0, forced)
    tried = []
    for variant in dict.fromkeys(candidates):
        if probe_variant(variant):
            return variant
        tried.append(variant)
    raise ImportError(f"no working Mitsuba variant among {tried}")


#: The variant used when the preferred one fails.
FALLBACK_VARIANT = "scalar_rgb"

#: The folder holding the ``meshadv`` package, put on the child's ``PYTHONPATH``.
_PACKAGE_PARENT = str(Path(__file__).resolve().parents[2])

#: The module run in the child process (``python -m``).
_WORKER_MODULE = "meshadv.transfer.mitsuba_worker"


class MitsubaRenderError(RuntimeError):
    """A Mitsuba render failed, crashed or timed out (the caller's process is unaffected)."""


@dataclass(frozen=True)
class MitsubaImage:
    """One Mitsuba render.

    Attributes:
        image: (H, W, 3) float32 linear RGB in [0, 1] (composited over the background when one was given).
        alpha: (H, W) float32 coverage of surfaces in [0, 1].
        variant: the Mitsuba variant that rendered it.
    """

    image: np.ndarray
    alpha: np.ndarray
    variant: str

    def chw(self) -> np.ndarray:
        """The image as (3, H, W), the layout of meshadv's ``RenderOutput.image[b]``."""
        return np.ascontiguousarray(self.image.transpose(2, 0, 1))


def _run_worker(specs: Sequence[SceneSpec], variant: str, timeout: float) -> list[MitsubaImage]:
    """Render ``specs`` in a child process (``python -m`` :data:`_WORKER_MODULE`) through a temporary folder: the
    specs go in pickled, the images come back in an ``.npz``.

    Raises:
        MitsubaRenderError: the child timed out, failed or wrote no images.
    """
    with tempfile.TemporaryDirectory(prefix="meshadv_mitsuba_") as tmp:
        in_path = os.path.join(tmp, "specs.pkl")
        out_path = os.path.join(tmp, "images.npz")
        with open(in_path, "wb") as fh:
            pickle.dump(list(specs), fh, protocol=pickle.HIGHEST_PROTOCOL)
        cmd = [sys.executable, "-m", _WORKER_MODULE, in_path, out_path, variant]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=_worker_environment())
        except subprocess.TimeoutExpired as exc:
            raise MitsubaRenderError(f"Mitsuba ({variant}) timed out after {timeout:.0f} s") from exc
        if proc.returncode != 0 or not os.path.exists(out_path):
            raise MitsubaRenderError(_failure_message(proc, variant))
        with np.load(out_path) as data:
            return [
                MitsubaImage(data[f"image_{i}"].copy(), data[f"alpha_{i}"].copy(), variant) for i in range(len(specs))
            ]


def _worker_environment() -> dict[str, str]:
    """This process's environment with this package's parent folder first on ``PYTHONPATH`` (the child imports
    the same meshadv, installed or not)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = _PACKAGE_PARENT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _failure_message(proc: subprocess.CompletedProcess, variant: str) -> str:
    """How the child failed (signal or exit code) and the last 15 lines of its standard error."""
    code = proc.returncode
    how = f"was killed by signal {-code}" if code < 0 else f"exited with {code}"
    tail = "\n".join(proc.stderr.strip().splitlines()[-15:])
    return f"Mitsuba ({variant}) {how}:\n{tail}"


def render_scenes(
    specs: Sequence[SceneSpec],
    *,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    fallback: bool = True,
) -> list[MitsubaImage]:
    """Render a batch of scenes with Mitsuba in one child process.

    Args:
        specs: the scenes.
        variant: Mitsuba variant; default :func:`~meshadv.transfer.mitsuba_process.best_variant`.
        timeout: seconds for the whole batch.
        fallback: retry with ``scalar_rgb`` when another variant fails.

    Returns:
        One :class:`MitsubaImage` per spec, in order.

    Raises:
        TypeError: ``specs`` contains something other than a SceneSpec, or ``timeout`` or ``variant`` has the wrong
            type.
        ValueError: ``timeout`` is not positive.
        MitsubaRenderError: rendering failed (crash, error or timeout), after the fallback.

    Example:
        >>> img = render_scenes([scene_spec(mesh, record, image_size=64)])[0].image  # doctest: +SKIP
    """
    specs = list(specs)
    for i, spec in enumerate(specs):
        if not isinstance(spec, SceneSpec):
            raise TypeError(f"specs[{i}] must be a SceneSpec, got {type(spec).__name__}")
    _validate.positive_float("timeout", timeout)
    if variant is not None and (not isinstance(variant, str) or not variant):
        raise TypeError(f"variant must be a Mitsuba variant name or None, got {variant!r}")
    if not specs:
        return []
    chosen = variant or best_variant()
    try:
        return _run_worker(specs, chosen, timeout)
    except MitsubaRenderError:
        if not fallback or chosen == FALLBACK_VARIANT:
            raise
        return _run_worker(specs, FALLBACK_VARIANT, timeout)


def render_scene(spec: SceneSpec, **kwargs: Any) -> MitsubaImage:
    """Render one scene (see :func:`render_scenes` for the keyword arguments)."""
    return render_scenes([spec], **kwargs)[0]


def render_mask(
    mesh: Any,
    camera: MitsubaCamera,
    image_size: Any = 224,
    *,
    spp: int = 1,
    **kwargs: Any,
) -> np.ndarray:
    """Render the coverage mask of a mesh with Mitsuba.

    With ``spp == 1`` one ray goes through each pixel centre, meshadv's coverage rule, so the mask is binary.

    Args:
        mesh: a ``meshadv.mesh.Mesh`` or :class:`~meshadv.transfer.mitsuba_spec.MeshObject`.
        camera: the camera.
        image_size: int or (H, W).
        spp: rays per pixel (> 1 gives fractional, anti-aliased coverage).
        **kwargs: passed to :func:`render_scenes`.

    Returns:
        (H, W) float32 coverage in [0, 1].
    """
    return render_scene(mask_spec(mesh, camera, image_size, spp=spp), **kwargs).alpha
