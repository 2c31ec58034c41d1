"""Darknet ``.cfg`` parsing, the network it describes, and the ``.weights`` binary format (read and write).

Supported layers: ``[convolutional]`` (``batch_normalize``, ``filters``, ``size``, ``stride``, ``pad``/``padding``,
``groups``, ``activation`` = leaky | linear | relu | mish | logistic), ``[shortcut]`` (``from``, linear activation),
``[route]`` (``layers``, relative or absolute), ``[upsample]`` (nearest, ``stride``), ``[maxpool]`` (Darknet's
padding rule) and ``[yolo]`` (``mask``, ``anchors``, ``classes``, ``num``, optional ``scale_x_y``). That covers
YOLOv3 and YOLOv3-tiny.

``.weights`` layout (little endian): header ``int32 major, int32 minor, int32 revision`` then ``seen`` as ``int64``
when ``major * 10 + minor >= 2`` (``int32`` otherwise), then float32 values layer by layer: for a convolution with
batch norm ``beta, gamma, running_mean, running_var, weights``; without batch norm ``bias, weights``.

Darknet's batch norm divides by ``sqrt(var) + 1e-6``; :class:`DarknetBatchNorm` does the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

__all__ = [
    "DarknetBatchNorm",
    "DarknetHeader",
    "DarknetNet",
    "YoloSpec",
    "load_darknet_weights",
    "parse_cfg",
    "save_darknet_weights",
]

PathLike = Union[str, Path]


@dataclass(frozen=True)
class DarknetHeader:
    """The ``.weights`` file header.

    Attributes:
        major: major version.
        minor: minor version.
        revision: revision.
        seen: number of training images seen (``int64`` on disk when ``major * 10 + minor >= 2``).
    """

    major: int = 0
    minor: int = 2
    revision: int = 0
    seen: int = 0

    @property
    def seen_is_int64(self) -> bool:
        """Whether ``seen`` is stored as int64."""
        return self.major * 10 + self.minor >= 2 and self.major < 1000 and self.minor < 1000


@dataclass(frozen=True)
class YoloSpec:
    """One ``[yolo]`` output layer.

    Attributes:
        anchors: ``(w, h)`` anchor sizes in network-input pixels, for this layer's masked anchors.
        num_classes: number of classes.
        scale_xy: ``scale_x_y`` (1 for YOLOv3).
    """

    anchors: tuple[tuple[float, float], ...]
    num_classes: int
    scale_xy: float = 1.0


def parse_cfg(path: PathLike) -> list[dict[str, str]]:
    """Parse a Darknet ``.cfg`` file into a list of sections.

    Args:
        path: the ``.cfg`` file.

    Returns:
        One dict per section, ``{"type": "net" | "convolutional" | ..., key: value, ...}``; the first is ``[net]``.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: malformed file (option outside a section, no ``[net]`` first, ``key=value`` missing ``=``).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"cfg file {path} does not exist (a Darknet .cfg such as yolov3.cfg)")
    sections: list[dict[str, str]] = []
    for lineno, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = raw.split("#", 1)[0].split(";", 1)[0].strip()
        if not line:
            continue
        if line.startswith("["):
            if not line.endswith("]"):
                raise ValueError(f"cfg {path}:{lineno}: malformed section header {raw!r}")
            sections.append({"type": line[1:-1].strip().lower()})
            continue
        if not sections:
            raise ValueError(f"cfg {path}:{lineno}: option {raw!r} outside any section")
        if "=" not in line:
            raise ValueError(f"cfg {path}:{lineno}: expected key=value, got {raw!r}")
        key, value = line.split("=", 1)
        sections[-1][key.strip()] = value.strip()
    if not sections or sections[0]["type"] not in ("net", "network"):
        raise ValueError(f"cfg {path}: the first section must be [net]")
    return sections


def _int(section: dict[str, str], key: str, default: int | None = None) -> int:
    if key not in section:
        if default is None:
            raise ValueError(f"cfg: [{section['type']}] needs {key}=")
        return default
    return int(section[key])


def _ints(value: str) -> list[int]:
    return [int(v) for v in value.split(",") if v.strip()]


class DarknetBatchNorm(nn.BatchNorm2d):
    """Batch norm in eval mode as Darknet computes it: ``gamma * (x - mean) / (sqrt(var) + 1e-6) + beta``."""

    def forward(self, x: Tensor) -> Tensor:
        """Normalise with the running statistics."""
        scale = self.weight / (self.running_var.sqrt() + 1e-6)
        shift = self.bias - self.running_mean * scale
        return x * scale.view(1, -1, 1, 1) + shift.view(1, -1, 1, 1)


class _Conv(nn.Module):
    def __init__(self, in_ch: int, section: dict[str, str]) -> None:
        super().__init__()
        filters = _int(section, "filters")
        size = _int(section, "size", 1)
        stride = _int(section, "stride", 1)
        groups = _int(section, "groups", 1)
        pad = size // 2 if _int(section, "pad", 0) else _int(section, "padding", 0)
        self.batch_normalize = bool(_int(section, "batch_normalize", 0))
        self.activation = section.get("activation", "logistic")
        if self.activation not in ("leaky", "linear", "relu", "mish", "logistic"):
            raise ValueError(f"cfg: unsupported activation {self.activation!r}")
        self.conv = nn.Conv2d(in_ch, filters, size, stride, pad, groups=groups, bias=not self.batch_normalize)
        self.bn = DarknetBatchNorm(filters) if self.batch_normalize else None
        self.out_channels = filters

    def forward(self, x: Tensor) -> Tensor:
        x = self.conv(x)
        if self.bn is not None:
            x = self.bn(x)
        if self.activation == "leaky":
            return F.leaky_relu(x, 0.1)
        if self.activation == "relu":
            return F.relu(x)
        if self.activation == "mish":
            return F.mish(x)
        if self.activation == "logistic":
            return torch.sigmoid(x)
        return x


class _MaxPool(nn.Module):
    def __init__(self, section: dict[str, str]) -> None:
        super().__init__()
        self.size = _int(section, "size", 2)
        self.stride = _int(section, "stride", self.size)
        self.pad = _int(section, "padding", self.size - 1)

    def forward(self, x: Tensor) -> Tensor:
        before = self.pad // 2
        after = self.pad - before
        x = F.pad(x, (before, after, before, after), value=float("-inf"))
        return F.max_pool2d(x, self.size, self.stride)


class DarknetNet(nn.Module):
    """The network described by a parsed Darknet cfg; ``forward`` returns the raw map of every ``[yolo]`` layer.

    Args:
        sections: output of :func:`parse_cfg`.

    Attributes:
        input_size: ``(height, width)`` from ``[net]``.
        yolo_specs: one :class:`YoloSpec` per ``[yolo]`` layer, in cfg order.

    Shape:
        - input: ``(B, C, height, width)`` (Darknet input: RGB in ``[0, 1]``).
        - output: list of ``(B, len(anchors) * (5 + classes), h_i, w_i)``, one per ``[yolo]`` layer.

    Raises:
        ValueError: unsupported layer type or inconsistent options.
    """

    def __init__(self, sections: list[dict[str, str]]) -> None:
        super().__init__()
        net = sections[0]
        self.input_size = (_int(net, "height", 416), _int(net, "width", 416))
        in_ch = _int(net, "channels", 3)
        self.layers = nn.ModuleList()
        self.kinds: list[str] = []
        self.refs: list[list[int]] = []
        self.yolo_specs: list[YoloSpec] = []
        out_channels: list[int] = []
        for i, section in enumerate(sections[1:]):
            kind = section["type"]
            refs: list[int] = []
            module: nn.Module = nn.Identity()
            if kind == "convolutional":
                conv = _Conv(in_ch, section)
                module, ch = conv, conv.out_channels
            elif kind == "shortcut":
                offset = _int(section, "from")
                refs = [offset + i if offset < 0 else offset]
                if section.get("activation", "linear") != "linear":
                    raise ValueError("cfg: only linear [shortcut] activation is supported")
                ch = out_channels[-1]
            elif kind == "route":
                if "groups" in section:
                    raise ValueError("cfg: [route] groups= is not supported")
                refs = [r + i if r < 0 else r for r in _ints(section["layers"])]
                ch = sum(out_channels[r] for r in refs)
            elif kind == "upsample":
                module = nn.Upsample(scale_factor=_int(section, "stride", 2), mode="nearest")
                ch = in_ch
            elif kind == "maxpool":
                module, ch = _MaxPool(section), in_ch
            elif kind == "yolo":
                anchors_flat = [float(v) for v in section["anchors"].split(",") if v.strip()]
                pairs = list(zip(anchors_flat[0::2], anchors_flat[1::2]))
                mask = _ints(section["mask"]) if "mask" in section else list(range(len(pairs)))
                spec = YoloSpec(
                    anchors=tuple(pairs[m] for m in mask),
                    num_classes=_int(section, "classes"),
                    scale_xy=float(section.get("scale_x_y", 1.0)),
                )
                if in_ch != len(spec.anchors) * (5 + spec.num_classes):
                    raise ValueError(
                        f"cfg: [yolo] layer {i} expects {len(spec.anchors) * (5 + spec.num_classes)} input "
                        f"channels ({len(spec.anchors)} anchors x (5 + {spec.num_classes})), got {in_ch}"
                    )
                self.yolo_specs.append(spec)
                ch = in_ch
            else:
                raise ValueError(f"cfg: unsupported layer type [{kind}] (layer {i})")
            for r in refs:
                if not 0 <= r < i:
                    raise ValueError(f"cfg: layer {i} [{kind}] refers to layer {r}, which is not before it")
            self.layers.append(module)
            self.kinds.append(kind)
            self.refs.append(refs)
            out_channels.append(ch)
            in_ch = ch
        if not self.yolo_specs:
            raise ValueError("cfg: no [yolo] layer")

    def forward(self, x: Tensor) -> list[Tensor]:
        """Raw outputs of every ``[yolo]`` layer."""
        outputs: list[Tensor] = []
        yolo: list[Tensor] = []
        for module, kind, refs in zip(self.layers, self.kinds, self.refs):
            if kind == "shortcut":
                x = x + outputs[refs[0]]
            elif kind == "route":
                x = torch.cat([outputs[r] for r in refs], dim=1)
            elif kind == "yolo":
                yolo.append(x)
            else:
                x = module(x)
            outputs.append(x)
        return yolo

    def conv_layers(self) -> list[_Conv]:
        """The convolution layers in file order."""
        return [m for m in self.layers if isinstance(m, _Conv)]


def _read_header(data: bytes, path: Path) -> tuple[DarknetHeader, int]:
    if len(data) < 16:
        raise ValueError(f"weights {path} is too short to be a Darknet .weights file ({len(data)} bytes)")
    major, minor, revision = np.frombuffer(data, dtype="<i4", count=3).tolist()
    probe = DarknetHeader(major, minor, revision)
    if probe.seen_is_int64:
        if len(data) < 20:
            raise ValueError(f"weights {path} is too short to be a Darknet .weights file")
        seen, offset = int(np.frombuffer(data, dtype="<i8", count=1, offset=12)[0]), 20
    else:
        seen, offset = int(np.frombuffer(data, dtype="<i4", count=1, offset=12)[0]), 16
    return DarknetHeader(major, minor, revision, seen), offset


def load_darknet_weights(net: DarknetNet, path: PathLike) -> DarknetHeader:
    """Load a Darknet ``.weights`` file into ``net`` (in place).

    Args:
        net: the network built from the matching cfg.
        path: the ``.weights`` file.

    Returns:
        The file header.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file holds fewer or more values than the cfg needs (wrong cfg / weights pair).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"weights file {path} does not exist (a Darknet .weights file such as yolov3.weights)")
    data = path.read_bytes()
    header, offset = _read_header(data, path)
    if (len(data) - offset) % 4:
        raise ValueError(f"weights {path}: payload is not a whole number of float32 values")
    values = np.frombuffer(data, dtype="<f4", offset=offset)
    needed = sum(p.numel() for conv in net.conv_layers() for p in _conv_tensors(conv))
    if values.size != needed:
        raise ValueError(
            f"weights {path} holds {values.size} values but the cfg needs {needed}: cfg and weights do not match"
        )
    pos = 0
    with torch.no_grad():
        for conv in net.conv_layers():
            for tensor in _conv_tensors(conv):
                n = tensor.numel()
                tensor.copy_(torch.from_numpy(values[pos : pos + n].copy()).view_as(tensor))
                pos += n
    return header


def _conv_tensors(conv: _Conv) -> list[Tensor]:
    if conv.bn is not None:
        return [conv.bn.bias, conv.bn.weight, conv.bn.running_mean, conv.bn.running_var, conv.conv.weight]
    return [conv.conv.bias, conv.conv.weight]  # type: ignore[list-item]  # bias exists without batch norm


def save_darknet_weights(net: DarknetNet, path: PathLike, header: DarknetHeader = DarknetHeader()) -> None:
    """Write ``net``'s parameters as a Darknet ``.weights`` file (inverse of :func:`load_darknet_weights`).

    Args:
        net: the network.
        path: output file (replaced atomically; its folder must exist).
        header: header to write.
    """
    parts = [np.array([header.major, header.minor, header.revision], dtype="<i4").tobytes()]
    parts.append(np.array([header.seen], dtype="<i8" if header.seen_is_int64 else "<i4").tobytes())
    for conv in net.conv_layers():
        for tensor in _conv_tensors(conv):
            parts.append(tensor.detach().cpu().numpy().astype("<f4").ravel().tobytes())
    from meshadv.util.atomic import write_bytes_atomic

    write_bytes_atomic(path, b"".join(parts))
