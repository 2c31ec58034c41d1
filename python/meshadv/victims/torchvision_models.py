"""The paper's ImageNet classifiers DenseNet-121 and Inception-v3 (torchvision architectures, user-supplied weights).

meshadv downloads nothing: pass the path of a state_dict saved with ``torch.save(model.state_dict(), path)`` (for
example torchvision's ``densenet121-a639ec97.pth`` / ``inception_v3_google-0cc3c7bd.pth`` fetched once by hand).

Preprocessing: DenseNet-121 at 224 px with torchvision's ImageNet mean/std; Inception-v3 at 299 px with
``(x - 0.5) / 0.5`` (the normalisation of Google's weights that torchvision ports; torchvision's ``transform_input``
does the same conversion, so it is turned off here and the normalisation is done once, explicitly).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor, nn

from meshadv.victims._weights import read_torch_state
from meshadv.victims.victim import ClassifierVictim, freeze
from meshadv.victims.preprocess import IMAGENET_MEAN, IMAGENET_STD, Preprocess

__all__ = ["TORCHVISION_SPECS", "TorchvisionVictim", "build_torchvision_model", "read_state_dict"]

#: name -> (input size, mean, std).
TORCHVISION_SPECS: dict[str, tuple[int, tuple[float, ...], tuple[float, ...]]] = {
    "densenet121": (224, IMAGENET_MEAN, IMAGENET_STD),
    "inception_v3": (299, (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)),
}

_DENSENET_OLD_KEY = re.compile(
    r"^(.*denselayer\d+\.(?:norm|relu|conv))\.((?:[12])\.(?:weight|bias|running_mean|running_var))$"
)


def read_state_dict(path: str | Path) -> dict[str, Tensor]:
    """Read a state_dict saved with ``torch.save``; unwraps ``{"state_dict": ...}`` / ``{"model": ...}`` and
    strips a ``module.`` prefix (DataParallel).

    Args:
        path: the ``.pth`` / ``.pt`` file.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is empty, truncated, not a torch file, carries pickled objects or does not hold a
            state_dict (the message names the file).
    """
    path = Path(path)
    state = read_torch_state(path)
    for key in ("state_dict", "model"):
        if isinstance(state, dict) and key in state and isinstance(state[key], dict):
            state = state[key]
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"weights {path} does not hold a state_dict (a dict of tensors)")
    if state and all(k.startswith("module.") for k in state):
        state = {k[len("module.") :]: v for k, v in state.items()}
    return state


def build_torchvision_model(name: str, state: dict[str, Tensor] | None = None) -> nn.Module:
    """Build the torchvision architecture ``name`` (random weights), matching ``state``'s layout when given.

    Args:
        name: ``"densenet121"`` or ``"inception_v3"``.
        state: a state_dict to be loaded later (used to decide whether Inception has its auxiliary head).

    Raises:
        ValueError: unknown ``name``.
    """
    import torchvision

    if name == "densenet121":
        return torchvision.models.densenet121(weights=None)
    if name == "inception_v3":
        aux = state is None or any(k.startswith("AuxLogits.") for k in state)
        return torchvision.models.inception_v3(weights=None, aux_logits=aux, transform_input=False, init_weights=False)
    raise ValueError(f"name must be one of {sorted(TORCHVISION_SPECS)}, got {name!r}")


class TorchvisionVictim(ClassifierVictim):
    """DenseNet-121 or Inception-v3 ImageNet classifier victim with its own resize + normalisation.

    Args:
        name: ``"densenet121"`` or ``"inception_v3"``.
        weights: path of a state_dict saved with ``torch.save`` (required: nothing is downloaded).
        device: torch device.
        mean: override the per-channel normalisation mean (``[0, 1]`` units).
        std: override the per-channel normalisation std.

    Shape:
        - input: ``(B, 3, H, W)`` in ``[0, 1]``, any size (resized to 224 / 299).
        - output: ``(B, 1000)`` logits.

    Raises:
        ValueError: unknown ``name``, ``weights`` not given, or keys that do not match the architecture.
        FileNotFoundError: ``weights`` does not exist.

    Example:
        >>> victim = TorchvisionVictim("densenet121", weights="densenet121-a639ec97.pth")  # doctest: +SKIP
    """

    def __init__(
        self,
        name: str,
        weights: str | Path | None = None,
        device: str | torch.device = "cpu",
        mean: Sequence[float] | None = None,
        std: Sequence[float] | None = None,
    ) -> None:
        if name not in TORCHVISION_SPECS:
            raise ValueError(f"name must be one of {sorted(TORCHVISION_SPECS)}, got {name!r}")
        if weights is None:
            raise ValueError(
                f"{name} needs weights=<path to a torchvision {name} state_dict saved with torch.save> "
                f"(meshadv downloads nothing; e.g. torchvision's {name} ImageNet weights file)"
            )
        size, default_mean, default_std = TORCHVISION_SPECS[name]
        super().__init__(name, (size, size))
        state = read_state_dict(weights)
        if name == "densenet121":
            state = {
                (_DENSENET_OLD_KEY.sub(r"\1\2", k) if _DENSENET_OLD_KEY.match(k) else k): v for k, v in state.items()
            }
        self.preprocess = Preprocess(
            (size, size), mean if mean is not None else default_mean, std if std is not None else default_std
        )
        self.net = build_torchvision_model(name, state)
        try:
            self.net.load_state_dict(state, strict=True)
        except RuntimeError as exc:
            raise ValueError(f"weights {weights} do not match the torchvision {name} architecture: {exc}") from exc
        freeze(self)
        self.to(device)

    def forward(self, images: Tensor) -> Tensor:
        """ImageNet logits ``(B, 1000)`` of ``[0, 1]`` images of any size."""
        out = self.net(self.preprocess(images))
        if isinstance(out, tuple):  # InceptionOutputs in train mode; never in eval, kept for safety
            out = out[0]
        return out
