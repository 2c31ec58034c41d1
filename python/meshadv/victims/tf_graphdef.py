"""Read a frozen TensorFlow ``GraphDef`` (``.pb``) without TensorFlow.

A frozen graph is a plain protocol-buffer message. This module decodes the small subset of the protobuf wire
format needed to recover every node's name, op, inputs and attributes, and the constant tensors (the trained
weights) stored in ``Const`` nodes. Only ``numpy`` is needed.

Messages decoded (field numbers from TensorFlow's ``graph.proto``, ``node_def.proto``, ``attr_value.proto``,
``tensor.proto``, ``tensor_shape.proto``)::

    GraphDef     { repeated NodeDef node = 1; }
    NodeDef      { string name = 1; string op = 2; repeated string input = 3; map<string, AttrValue> attr = 5; }
    AttrValue    { ListValue list = 1; bytes s = 2; int64 i = 3; float f = 4; bool b = 5; DataType type = 6;
                   TensorShapeProto shape = 7; TensorProto tensor = 8; }
    ListValue    { repeated bytes s = 2; repeated int64 i = 3; repeated float f = 4; repeated bool b = 5;
                   repeated DataType type = 6; }
    TensorProto  { DataType dtype = 1; TensorShapeProto tensor_shape = 2; bytes tensor_content = 4;
                   repeated float float_val = 5; repeated double double_val = 6; repeated int32 int_val = 7;
                   repeated bytes string_val = 8;
                   repeated int64 int64_val = 10; repeated bool bool_val = 11; }
    TensorShapeProto { repeated Dim dim = 2; }   Dim { int64 size = 1; }

Example:
    >>> graph = read_graphdef("frozen_inference_graph.pb")          # doctest: +SKIP
    >>> graph.constant("FeatureExtractor/MobilenetV2/Conv/weights").shape  # doctest: +SKIP
    (3, 3, 3, 32)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterator, List, Tuple, Union

import numpy as np

__all__ = ["NodeDef", "GraphDef", "read_graphdef", "parse_graphdef"]

# TensorFlow DataType enum values -> numpy dtypes (the ones frozen inference graphs use).
_TF_DTYPES: Dict[int, np.dtype] = {
    1: np.dtype("<f4"),  # DT_FLOAT
    2: np.dtype("<f8"),  # DT_DOUBLE
    3: np.dtype("<i4"),  # DT_INT32
    4: np.dtype("u1"),  # DT_UINT8
    5: np.dtype("<i2"),  # DT_INT16
    6: np.dtype("i1"),  # DT_INT8
    9: np.dtype("<i8"),  # DT_INT64
    10: np.dtype("?"),  # DT_BOOL
}

_DT_STRING = 7

# Wire types.
_VARINT, _I64, _LEN, _I32 = 0, 1, 2, 5


def _read_varint(buf: memoryview, pos: int) -> Tuple[int, int]:
    """Decode a base-128 varint at ``pos``; return (value, new position)."""
    result = 0
    shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if byte < 0x80:
            return result, pos
        shift += 7
        if shift > 70:
            raise ValueError("protobuf: varint too long")


def _fields(buf: memoryview) -> Iterator[Tuple[int, int, Any]]:
    """Iterate over (field number, wire type, value) of one message; LEN values are memoryviews."""
    pos = 0
    end = len(buf)
    while pos < end:
        key, pos = _read_varint(buf, pos)
        number, wire = key >> 3, key & 7
        if wire == _VARINT:
            value, pos = _read_varint(buf, pos)
        elif wire == _LEN:
            size, pos = _read_varint(buf, pos)
            if pos + size > end:
                raise ValueError("protobuf: length-delimited field runs past the end")
            value = buf[pos : pos + size]
            pos += size
        elif wire == _I64:
            value = buf[pos : pos + 8]
            pos += 8
        elif wire == _I32:
            value = buf[pos : pos + 4]
            pos += 4
        else:
            raise ValueError(f"protobuf: unsupported wire type {wire}")
        yield number, wire, value


def _signed64(value: int) -> int:
    """Reinterpret an unsigned varint as a two's-complement int64."""
    return value - (1 << 64) if value >= (1 << 63) else value


def _packed_varints(value: Any, wire: int) -> List[int]:
    """Values of a repeated varint field, packed (LEN) or not."""
    if wire == _VARINT:
        return [_signed64(value)]
    out = []
    pos = 0
    while pos < len(value):
        v, pos = _read_varint(value, pos)
        out.append(_signed64(v))
    return out


def _packed_fixed(value: Any, wire: int, fmt: str) -> List[float]:
    """Values of a repeated fixed-width field (``fmt`` is ``'f'`` or ``'d'``), packed or not."""
    return list(struct.unpack(f"<{len(value) // struct.calcsize(fmt)}{fmt}", bytes(value)))


def _parse_shape(buf: memoryview) -> Tuple[int, ...]:
    """Decode a TensorShapeProto into a tuple of sizes (-1 for unknown)."""
    dims = []
    for number, _, value in _fields(buf):
        if number == 2:
            size = 0
            for n2, _, v2 in _fields(value):
                if n2 == 1:
                    size = _signed64(v2)
            dims.append(size)
    return tuple(dims)


def _parse_tensor(buf: memoryview) -> np.ndarray:
    """Decode a TensorProto into a numpy array (a copy, little-endian, C order)."""
    dtype_enum = 0
    shape: Tuple[int, ...] = ()
    content = None
    values: List[Any] = []
    for number, wire, value in _fields(buf):
        if number == 1:
            dtype_enum = value
        elif number == 2:
            shape = _parse_shape(value)
        elif number == 4:
            content = bytes(value)
        elif number == 5:
            values.extend(_packed_fixed(value, wire, "f"))
        elif number == 6:
            values.extend(_packed_fixed(value, wire, "d"))
        elif number in (7, 10, 11):
            values.extend(_packed_varints(value, wire))
        elif number == 8:
            values.append(bytes(value))
    if dtype_enum == _DT_STRING:
        return np.asarray(values, dtype=object).reshape(shape if len(values) > 1 else shape or ())
    if dtype_enum not in _TF_DTYPES:
        raise ValueError(f"unsupported TensorProto dtype enum {dtype_enum}")
    dtype = _TF_DTYPES[dtype_enum]
    count = int(np.prod(shape)) if shape else 1
    if content is not None:
        return np.frombuffer(content, dtype=dtype).reshape(shape).copy()
    if not values:
        return np.zeros(shape, dtype=dtype)
    array = np.asarray(values, dtype=dtype)
    if array.size == count:
        return array.reshape(shape)
    # TensorFlow stores a splat as a single value (or a prefix whose last value repeats).
    full = np.empty(count, dtype=dtype)
    full[: array.size] = array
    full[array.size :] = array[-1]
    return full.reshape(shape)


def _parse_attr(buf: memoryview) -> Any:
    """Decode an AttrValue into a Python value (bytes, int, float, bool, shape tuple, ndarray or list)."""
    for number, wire, value in _fields(buf):
        if number == 2:
            return bytes(value)
        if number == 3:
            return _signed64(value)
        if number == 4:
            return struct.unpack("<f", bytes(value))[0]
        if number == 5:
            return bool(value)
        if number == 6:
            return int(value)
        if number == 7:
            return _parse_shape(value)
        if number == 8:
            return _parse_tensor(value)
        if number == 1:
            items: List[Any] = []
            for n2, w2, v2 in _fields(value):
                if n2 == 2:
                    items.append(bytes(v2))
                elif n2 in (3, 6):
                    items.extend(_packed_varints(v2, w2))
                elif n2 == 4:
                    items.extend(_packed_fixed(v2, w2, "f"))
                elif n2 == 5:
                    items.extend(bool(v) for v in _packed_varints(v2, w2))
            return items
    return None


@dataclass
class NodeDef:
    """One graph node.

    Attributes:
        name: unique node name, e.g. ``"FeatureExtractor/MobilenetV2/Conv/weights"``.
        op: the op type, e.g. ``"Const"``, ``"Conv2D"``.
        inputs: names of the input nodes (control inputs keep their ``^`` prefix).
        attrs: decoded attributes; a ``Const`` node's tensor is ``attrs["value"]`` (an ``np.ndarray``).
    """

    name: str
    op: str
    inputs: List[str] = field(default_factory=list)
    attrs: Dict[str, Any] = field(default_factory=dict)


@dataclass
class GraphDef:
    """A decoded graph: nodes by name, in file order."""

    nodes: Dict[str, NodeDef]

    def constant(self, name: str) -> np.ndarray:
        """Return the tensor of the ``Const`` node ``name`` (following ``Identity`` nodes).

        Raises:
            KeyError: no node of that name, or it does not resolve to a ``Const`` node.
        """
        node = self.nodes.get(name)
        seen = 0
        while node is not None and node.op == "Identity" and seen < 64:
            node = self.nodes.get(node.inputs[0])
            seen += 1
        if node is None or node.op != "Const":
            raise KeyError(f"graph has no constant named {name!r}")
        return node.attrs["value"]


def parse_graphdef(data: bytes) -> GraphDef:
    """Decode a serialized ``GraphDef``.

    Args:
        data: the bytes of a frozen ``.pb`` graph.

    Returns:
        The decoded graph.

    Raises:
        ValueError: the bytes are not a well-formed GraphDef.
    """
    nodes: Dict[str, NodeDef] = {}
    try:
        for number, wire, value in _fields(memoryview(data)):
            if number != 1 or wire != _LEN:
                continue
            node = NodeDef(name="", op="")
            for n2, _, v2 in _fields(value):
                if n2 == 1:
                    node.name = bytes(v2).decode()
                elif n2 == 2:
                    node.op = bytes(v2).decode()
                elif n2 == 3:
                    node.inputs.append(bytes(v2).decode())
                elif n2 == 5:
                    key, attr = "", None
                    for n3, _, v3 in _fields(v2):
                        if n3 == 1:
                            key = bytes(v3).decode()
                        elif n3 == 2:
                            attr = _parse_attr(v3)
                    node.attrs[key] = attr
            nodes[node.name] = node
    except (IndexError, UnicodeDecodeError, struct.error, ValueError) as exc:
        raise ValueError(f"malformed GraphDef: {exc}") from exc
    if not nodes:
        raise ValueError("malformed GraphDef: no nodes found")
    return GraphDef(nodes=nodes)


def read_graphdef(path: Union[str, Path]) -> GraphDef:
    """Read and decode a frozen ``GraphDef`` file.

    Args:
        path: path of the ``.pb`` file.

    Returns:
        The decoded graph.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is not a well-formed GraphDef.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: GraphDef file not found: {path}")
    return parse_graphdef(path.read_bytes())
