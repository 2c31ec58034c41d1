"""Victim base classes and the detector output dataclasses shared by every victim.

A *victim* is a frozen, eval-mode ``torch.nn.Module`` that takes rendered images in ``[0, 1]`` of any size,
``(B, 3, H, W)``, does its own differentiable preprocessing (resize, normalisation) and returns either ImageNet
logits (classifiers) or a :class:`DetectorOutput` (detectors). Gradients flow back to the input image.

Example:
    >>> from meshadv.victims import load_victim
    >>> victim = load_victim("efficientnet_lite0")      # doctest: +SKIP
    >>> logits = victim(images)                          # doctest: +SKIP  (B, 1000)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

__all__ = [
    "ClassifierVictim",
    "Detections",
    "DetectorOutput",
    "DetectorVictim",
    "Victim",
    "check_images",
    "freeze",
]


def check_images(images: Tensor, name: str = "images") -> Tensor:
    """Validate a batch of images for a victim.

    Args:
        images: float tensor ``(B, 3, H, W)`` with values in ``[0, 1]`` (not checked, clipping is the caller's job).
        name: argument name used in error messages.

    Returns:
        The same tensor.

    Raises:
        ValueError: wrong type, rank, channel count, empty batch or non-floating dtype.
    """
    if not isinstance(images, Tensor):
        raise ValueError(  # noqa: TRY004 - the team convention: bad input is a ValueError
            f"{name} must be a torch.Tensor of shape (B, 3, H, W), got {type(images).__name__}"
        )
    if images.dim() != 4 or images.shape[1] != 3:
        raise ValueError(f"{name} must have shape (B, 3, H, W), got {tuple(images.shape)}")
    if images.shape[0] == 0 or images.shape[2] == 0 or images.shape[3] == 0:
        raise ValueError(f"{name} must be non-empty, got shape {tuple(images.shape)}")
    if not images.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor in [0, 1], got dtype {images.dtype}")
    return images


def freeze(module: nn.Module) -> nn.Module:
    """Put ``module`` in eval mode and turn off ``requires_grad`` on all its parameters.

    Args:
        module: the network to freeze.

    Returns:
        The same module, frozen.
    """
    module.eval()
    for param in module.parameters():
        param.requires_grad_(False)
    return module


class Victim(nn.Module):
    """Base class of all victims: a frozen eval-mode model with differentiable preprocessing.

    Subclasses set :attr:`kind` (``"classifier"`` or ``"detector"``), :attr:`name` and :attr:`input_size` and implement
    :meth:`forward`. ``train()`` is a no-op that keeps the model in eval mode (batch-norm statistics never change).

    Attributes:
        name: the registry name, e.g. ``"efficientnet_lite0"``.
        kind: ``"classifier"`` or ``"detector"``.
        input_size: ``(H, W)`` the network sees after the internal resize.
    """

    kind: ClassVar[str] = ""

    def __init__(self, name: str, input_size: tuple[int, int]) -> None:
        super().__init__()
        self.name = name
        self.input_size = (int(input_size[0]), int(input_size[1]))

    @property
    def device(self) -> torch.device:
        """The device the network runs on (that of its first parameter or buffer; CPU when it has none)."""
        for tensor in self.parameters():
            return tensor.device
        for tensor in self.buffers():
            return tensor.device
        return torch.device("cpu")

    def __call__(self, images: Tensor, *args: Any, **kwargs: Any) -> Any:
        """Run :meth:`forward` on the victim's device and return the output on the device of ``images``.

        Images rendered on the CPU for a victim on a GPU are copied once (from pinned memory, without blocking the
        host), the output comes back to the CPU, and autograd moves the output's cotangent to the GPU and the
        input gradient back to the CPU, so an attack loop that renders on the CPU needs no change. When the images
        are already on the victim's device nothing is copied.
        """
        device = self.device
        if not isinstance(images, Tensor) or images.device == device:
            return super().__call__(images, *args, **kwargs)
        if images.device.type == "cpu" and device.type == "cuda":
            moved = images.pin_memory().to(device, non_blocking=True)
        else:
            moved = images.to(device)
        return _to_device(super().__call__(moved, *args, **kwargs), images.device)

    def train(self, mode: bool = True) -> Victim:
        """Keep the victim in eval mode whatever ``mode`` is (victims are never trained).

        Args:
            mode: ignored.

        Returns:
            self.
        """
        return super().train(False)

    def resize(self, images: Tensor) -> Tensor:
        """Differentiably resize ``images`` to :attr:`input_size` (bilinear, antialiased when shrinking).

        Args:
            images: ``(B, 3, H, W)`` in ``[0, 1]``.

        Returns:
            ``(B, 3, *input_size)``; the input itself when it already has that size.
        """
        check_images(images)
        if tuple(images.shape[-2:]) == self.input_size:
            return images
        shrinking = images.shape[-2] > self.input_size[0] or images.shape[-1] > self.input_size[1]
        return nn.functional.interpolate(
            images, size=self.input_size, mode="bilinear", align_corners=False, antialias=shrinking
        )


def _to_device(output: Any, device: torch.device) -> Any:
    """A victim's output (logits or a :class:`DetectorOutput`) on ``device``, differentiably."""
    if isinstance(output, Tensor):
        return output.to(device)
    if isinstance(output, DetectorOutput):
        return DetectorOutput(
            boxes=output.boxes.to(device),
            objectness=None if output.objectness is None else output.objectness.to(device),
            class_probs=output.class_probs.to(device),
        )
    return output


class ClassifierVictim(Victim):
    """An ImageNet-1k classifier: ``victim(images) -> logits (B, 1000)``.

    Shape:
        - images: ``(B, 3, H, W)`` float in ``[0, 1]``, any ``H, W``.
        - output: ``(B, 1000)`` logits (pre-softmax), ImageNet class order.
    """

    kind: ClassVar[str] = "classifier"

    @property
    def class_names(self) -> tuple[str, ...]:
        """The 1000 ImageNet class names in logit order."""
        from meshadv.victims.labels import imagenet_class_names

        return imagenet_class_names()

    def predict(self, images: Tensor) -> Tensor:
        """Top-1 ImageNet indices, without gradients.

        Args:
            images: ``(B, 3, H, W)`` in ``[0, 1]``.

        Returns:
            int64 ``(B,)``.
        """
        with torch.no_grad():
            return self(images).argmax(dim=1)


@dataclass(frozen=True)
class DetectorOutput:
    """Raw (pre-NMS) detector output, one row per anchor / grid cell / box, as the disappearance loss needs it.

    Attributes:
        boxes: ``(B, A, 4)`` boxes ``(x1, y1, x2, y2)`` normalised to ``[0, 1]`` of the input image (not clipped).
        objectness: ``(B, A)`` probability that the box holds an object, or ``None`` for models without one (SSD).
        class_probs: ``(B, A, K)`` per-class probabilities aligned with the victim's ``class_names`` (K entries,
            no background column). For YOLO they are conditional on an object (sigmoid outputs); for SSD they are
            the softmax probabilities of the K foreground classes.
    """

    boxes: Tensor
    objectness: Tensor | None
    class_probs: Tensor

    def __post_init__(self) -> None:
        if self.boxes.dim() != 3 or self.boxes.shape[-1] != 4:
            raise ValueError(f"boxes must have shape (B, A, 4), got {tuple(self.boxes.shape)}")
        if self.class_probs.dim() != 3 or self.class_probs.shape[:2] != self.boxes.shape[:2]:
            raise ValueError(
                f"class_probs must have shape (B, A, K) matching boxes {tuple(self.boxes.shape[:2])}, "
                f"got {tuple(self.class_probs.shape)}"
            )
        if self.objectness is not None and self.objectness.shape != self.boxes.shape[:2]:
            raise ValueError(
                f"objectness must have shape (B, A) = {tuple(self.boxes.shape[:2])}, got {tuple(self.objectness.shape)}"
            )

    def scores(self) -> Tensor:
        """Per-class detection scores ``(B, A, K)``: ``objectness * class_probs`` (or ``class_probs`` alone)."""
        if self.objectness is None:
            return self.class_probs
        return self.objectness.unsqueeze(-1) * self.class_probs


@dataclass(frozen=True)
class Detections:
    """Final detections of one image after score thresholding and NMS, for reporting.

    Attributes:
        boxes: ``(D, 4)`` ``(x1, y1, x2, y2)`` normalised to ``[0, 1]``, clipped to the image.
        scores: ``(D,)`` detection scores, in descending order.
        labels: int64 ``(D,)`` class indices into ``class_names``.
        class_names: names of all the detector's classes.
    """

    boxes: Tensor
    scores: Tensor
    labels: Tensor
    class_names: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.scores.shape[0])

    def names(self) -> list[str]:
        """Class names of the detections, in order."""
        return [self.class_names[int(i)] for i in self.labels.tolist()]

    def to_records(self) -> list[dict]:
        """JSON-able list of ``{"label", "score", "box"}`` dicts."""
        return [
            {"label": self.class_names[int(lab)], "score": float(s), "box": [float(v) for v in box]}
            for lab, s, box in zip(self.labels.tolist(), self.scores.tolist(), self.boxes.tolist())
        ]


class DetectorVictim(Victim):
    """An object detector: ``victim(images) -> DetectorOutput``; :meth:`detect` gives NMS-filtered detections.

    Subclasses set :attr:`class_names` (a tuple of K names matching ``class_probs``).

    Shape:
        - images: ``(B, 3, H, W)`` float in ``[0, 1]``, any ``H, W``.
        - output: :class:`DetectorOutput` with ``A`` raw boxes per image.
    """

    kind: ClassVar[str] = "detector"

    def __init__(self, name: str, input_size: tuple[int, int], class_names: Sequence[str]) -> None:
        super().__init__(name, input_size)
        self.class_names: tuple[str, ...] = tuple(class_names)

    def class_index(self, class_name: str) -> int:
        """Index of ``class_name`` in :attr:`class_names`.

        Raises:
            ValueError: unknown class name.
        """
        try:
            return self.class_names.index(class_name)
        except ValueError:
            raise ValueError(
                f"class_name {class_name!r} is not a class of {self.name}; known: {', '.join(self.class_names)}"
            ) from None

    def detect(
        self,
        images: Tensor,
        score_threshold: float = 0.5,
        iou_threshold: float = 0.5,
        max_detections: int = 100,
    ) -> list[Detections]:
        """Decode, threshold and class-wise NMS-filter the detections of each image (no gradients).

        Args:
            images: ``(B, 3, H, W)`` in ``[0, 1]``.
            score_threshold: keep (box, class) pairs whose score (objectness x class probability) is at least this.
            iou_threshold: NMS IoU threshold, applied per class to the boxes clipped to the image.
            max_detections: keep at most this many detections per image.

        Returns:
            One :class:`Detections` per image.

        Raises:
            ValueError: thresholds outside ``[0, 1]`` or ``max_detections < 1``.
        """
        if not 0.0 <= score_threshold <= 1.0:
            raise ValueError(f"score_threshold must be in [0, 1], got {score_threshold}")
        if not 0.0 <= iou_threshold <= 1.0:
            raise ValueError(f"iou_threshold must be in [0, 1], got {iou_threshold}")
        if max_detections < 1:
            raise ValueError(f"max_detections must be >= 1, got {max_detections}")
        with torch.no_grad():
            out = self(images)
        return postprocess_detections(out, self.class_names, score_threshold, iou_threshold, max_detections)


def postprocess_detections(
    out: DetectorOutput,
    class_names: Sequence[str],
    score_threshold: float = 0.5,
    iou_threshold: float = 0.5,
    max_detections: int = 100,
) -> list[Detections]:
    """Threshold and class-wise NMS a :class:`DetectorOutput` into one :class:`Detections` per image.

    Args:
        out: raw detector output.
        class_names: names aligned with ``out.class_probs``'s last dimension.
        score_threshold: minimum score of a (box, class) pair.
        iou_threshold: NMS IoU threshold (per class).
        max_detections: maximum detections kept per image.

    Returns:
        One :class:`Detections` per image, sorted by descending score.
    """
    from torchvision.ops import batched_nms

    names = tuple(class_names)
    if out.class_probs.shape[-1] != len(names):
        raise ValueError(f"class_names has {len(names)} entries but class_probs has {out.class_probs.shape[-1]}")
    scores_all = out.scores().detach()
    boxes_all = out.boxes.detach()
    results = []
    for b in range(boxes_all.shape[0]):
        anchor_idx, class_idx = torch.nonzero(scores_all[b] >= score_threshold, as_tuple=True)
        scores = scores_all[b, anchor_idx, class_idx].float()
        boxes = boxes_all[b, anchor_idx].float().clamp(0.0, 1.0)
        keep = batched_nms(boxes, scores, class_idx, iou_threshold)[:max_detections]
        results.append(
            Detections(
                boxes=boxes[keep],
                scores=scores[keep],
                labels=class_idx[keep].to(torch.int64),
                class_names=names,
            )
        )
    return results
