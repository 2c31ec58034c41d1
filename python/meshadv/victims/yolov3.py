"""YOLOv3 detector victim from a Darknet ``.cfg`` + ``.weights`` pair given by the user (nothing is downloaded).

Decoding of each ``[yolo]`` layer (Redmon & Farhadi 2018), for the cell at column ``cx``, row ``cy`` of a ``W x H`` grid
and anchor ``(aw, ah)`` in network-input pixels (``net_w x net_h``)::

    x = (sigmoid(tx) + cx) / W          y = (sigmoid(ty) + cy) / H        (box centre, [0, 1] of the image)
    w = exp(tw) * aw / net_w            h = exp(th) * ah / net_h
    objectness = sigmoid(to)            class_probs = sigmoid(tc)         (80 independent logistic classes)

The raw boxes of all layers are concatenated in cfg order; within a layer they are ordered (row, column, anchor), so
YOLOv3 at 416 px gives ``A = 3 * (13^2 + 26^2 + 52^2) = 10647`` boxes. The image is resized (not letterboxed) to the
network size, so normalised boxes refer directly to the input image. Darknet input is RGB in ``[0, 1]``, with no
normalisation.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Union

import torch
from torch import Tensor

from meshadv.victims.victim import DetectorOutput, DetectorVictim, check_images, freeze
from meshadv.victims.darknet import DarknetHeader, DarknetNet, YoloSpec, load_darknet_weights, parse_cfg
from meshadv.victims.labels import coco_class_names

__all__ = ["YOLOv3Victim", "decode_yolo_layer"]

PathLike = Union[str, Path]


def decode_yolo_layer(raw: Tensor, spec: YoloSpec, net_size: tuple[int, int]) -> tuple[Tensor, Tensor, Tensor]:
    """Decode one ``[yolo]`` layer's raw map into boxes, objectness and class probabilities (differentiable).

    Args:
        raw: ``(B, nA * (5 + K), H, W)`` raw network output.
        spec: the layer's anchors and class count.
        net_size: ``(net_h, net_w)`` network input size in pixels (anchors are in these pixels).

    Returns:
        ``boxes (B, H*W*nA, 4)`` xyxy in ``[0, 1]``, ``objectness (B, H*W*nA)``, ``class_probs (B, H*W*nA, K)``;
        rows ordered (row, column, anchor).

    Raises:
        ValueError: channel count does not match the spec.
    """
    batch, channels, height, width = raw.shape
    num_anchors, num_classes = len(spec.anchors), spec.num_classes
    if channels != num_anchors * (5 + num_classes):
        raise ValueError(f"raw must have {num_anchors * (5 + num_classes)} channels, got {channels}")
    pred = raw.view(batch, num_anchors, 5 + num_classes, height, width).permute(0, 3, 4, 1, 2)  # B,H,W,nA,5+K
    rows = torch.arange(height, dtype=raw.dtype, device=raw.device).view(1, height, 1, 1)
    cols = torch.arange(width, dtype=raw.dtype, device=raw.device).view(1, 1, width, 1)
    anchors = torch.tensor(spec.anchors, dtype=raw.dtype, device=raw.device)  # nA, 2
    scale = spec.scale_xy
    sx = torch.sigmoid(pred[..., 0]) * scale - 0.5 * (scale - 1.0)
    sy = torch.sigmoid(pred[..., 1]) * scale - 0.5 * (scale - 1.0)
    cx = (sx + cols) / width
    cy = (sy + rows) / height
    bw = torch.exp(pred[..., 2]) * anchors[:, 0] / net_size[1]
    bh = torch.exp(pred[..., 3]) * anchors[:, 1] / net_size[0]
    boxes = torch.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], dim=-1)
    objectness = torch.sigmoid(pred[..., 4])
    class_probs = torch.sigmoid(pred[..., 5:])
    count = height * width * num_anchors
    return (
        boxes.reshape(batch, count, 4),
        objectness.reshape(batch, count),
        class_probs.reshape(batch, count, num_classes),
    )


class YOLOv3Victim(DetectorVictim):
    """A Darknet YOLO detector (YOLOv3, YOLOv3-tiny, ...) as a victim.

    Args:
        net: the network built from the cfg (weights loaded).
        class_names: names of the ``K`` classes; default the 80 COCO names when ``K == 80``, else ``class_<i>``.
        name: victim name.
        header: the weights file header, kept for reference.

    Shape:
        - input: ``(B, 3, H, W)`` in ``[0, 1]``, any size (resized to the cfg's ``width x height``).
        - output: :class:`DetectorOutput` with ``objectness`` ``(B, A)`` and sigmoid ``class_probs`` ``(B, A, K)``.

    Example:
        >>> victim = YOLOv3Victim.from_darknet("yolov3.cfg", "yolov3.weights")   # doctest: +SKIP
        >>> victim.detect(images)[0].names()                                       # doctest: +SKIP
    """

    def __init__(
        self,
        net: DarknetNet,
        class_names: Sequence[str] | None = None,
        name: str = "yolov3",
        header: DarknetHeader | None = None,
    ) -> None:
        num_classes = {spec.num_classes for spec in net.yolo_specs}
        if len(num_classes) != 1:
            raise ValueError(f"net: all [yolo] layers must have the same classes=, got {sorted(num_classes)}")
        k = num_classes.pop()
        if class_names is None:
            class_names = coco_class_names() if k == 80 else tuple(f"class_{i}" for i in range(k))
        if len(class_names) != k:
            raise ValueError(f"class_names has {len(class_names)} names but the cfg has classes={k}")
        super().__init__(name, net.input_size, class_names)
        self.net = net
        self.header = header
        freeze(self)

    @classmethod
    def from_darknet(
        cls,
        cfg: PathLike,
        weights: PathLike,
        *,
        class_names: Sequence[str] | None = None,
        device: str | torch.device = "cpu",
        name: str = "yolov3",
    ) -> YOLOv3Victim:
        """Build from a Darknet ``.cfg`` and ``.weights`` pair.

        Args:
            cfg: the ``.cfg`` path.
            weights: the ``.weights`` path.
            class_names: class names (default COCO for 80 classes).
            device: torch device.
            name: victim name.

        Raises:
            FileNotFoundError: ``cfg`` or ``weights`` does not exist.
            ValueError: malformed cfg or a cfg/weights mismatch.
        """
        weights = Path(weights)
        if not weights.is_file():
            raise FileNotFoundError(
                f"weights file {weights} does not exist (pass weights=<path to a Darknet .weights file such as "
                "yolov3.weights>)"
            )
        net = DarknetNet(parse_cfg(cfg))
        header = load_darknet_weights(net, weights)
        return cls(net, class_names=class_names, name=name, header=header).to(device)

    def forward(self, images: Tensor) -> DetectorOutput:
        """Raw decoded detections of ``[0, 1]`` images of any size."""
        check_images(images)
        raws = self.net(self.resize(images))
        parts: list[tuple[Tensor, Tensor, Tensor]] = [
            decode_yolo_layer(raw, spec, self.input_size) for raw, spec in zip(raws, self.net.yolo_specs)
        ]
        return DetectorOutput(
            boxes=torch.cat([p[0] for p in parts], dim=1),
            objectness=torch.cat([p[1] for p in parts], dim=1),
            class_probs=torch.cat([p[2] for p in parts], dim=1),
        )
