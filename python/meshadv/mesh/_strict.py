"""Structure checks for text mesh files (OBJ, OFF, ASCII PLY) before trimesh reads them.

trimesh reads these formats leniently: an ASCII PLY whose header announces 4 vertices but holds 3 reads a face
line as a vertex, ``element face 1000`` with one face line loads one face, an OFF file's counts are not checked,
an OBJ ``f 0 1 2`` (OBJ indices start at 1) silently wraps to the last vertex and ``v 0 1`` fails deep inside
NumPy. These checks walk the file once, compare it with its own declarations and raise
:class:`~meshadv.mesh.errors.MeshLoadError` naming the file and the line. (Binary PLY is checked by trimesh, which
refuses a file of the wrong length.)
"""

from __future__ import annotations

from pathlib import Path

from meshadv.mesh.errors import MeshLoadError

__all__ = ["check_ascii_ply", "check_obj", "check_off"]

_PLY_SCALARS = {
    "char", "uchar", "short", "ushort", "int", "uint", "float", "double",
    "int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64",
}  # fmt: skip


def _number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _obj_index(token: str, path: Path, lineno: int) -> int:
    head = token.split("/", 1)[0]
    try:
        return int(head)
    except ValueError:
        raise MeshLoadError(f"{path}:{lineno}: face corner {token!r} is not a vertex index") from None


def check_obj(text: str, path: Path) -> None:
    """Check OBJ ``v`` lines hold at least 3 numbers and ``f`` indices refer to existing vertices (1-based).

    Raises:
        MeshLoadError: the first malformed line, with its number.
    """
    vertices = 0
    faces: "list[tuple[int, int, int]]" = []  # (line, smallest index, largest index) of 1-based positive refs
    for lineno, line in enumerate(text.splitlines(), 1):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        head = tokens[0]
        if head == "v":
            values = tokens[1:]
            if len(values) < 3 or not all(_number(t) for t in values):
                raise MeshLoadError(f"{path}:{lineno}: a vertex needs 3 numbers (x y z), got {line.strip()!r}")
            vertices += 1
        elif head == "f":
            corners = tokens[1:]
            if len(corners) < 3:
                raise MeshLoadError(f"{path}:{lineno}: a face needs at least 3 corners, got {line.strip()!r}")
            indices = [_obj_index(t, path, lineno) for t in corners]
            if 0 in indices:
                raise MeshLoadError(f"{path}:{lineno}: OBJ vertex indices start at 1, got 0 in {line.strip()!r}")
            for i in indices:
                if i < 0 and -i > vertices:
                    raise MeshLoadError(
                        f"{path}:{lineno}: relative index {i} refers before the first vertex ({vertices} so far)"
                    )
            positive = [i for i in indices if i > 0]
            if positive:
                faces.append((lineno, min(positive), max(positive)))
    for lineno, _low, high in faces:
        if high > vertices:
            raise MeshLoadError(f"{path}:{lineno}: vertex index {high} is out of range (the file has {vertices})")


def _data_lines(text: str) -> "list[tuple[int, list[str]]]":
    out = []
    for lineno, line in enumerate(text.splitlines(), 1):
        tokens = line.split("#", 1)[0].split()
        if tokens:
            out.append((lineno, tokens))
    return out


def check_off(text: str, path: Path) -> None:
    """Check an OFF file's vertex and face counts against its body, and its face indices against the vertices.

    Raises:
        MeshLoadError: bad header, a count mismatch, a short line or an out-of-range index, naming the line.
    """
    lines = _data_lines(text)
    if not lines or not lines[0][1][0].upper().endswith("OFF"):
        raise MeshLoadError(f"{path}: an OFF file must start with 'OFF'")
    if "BINARY" in (t.upper() for t in lines[0][1]):
        return  # binary OFF: trimesh reads it by byte counts
    header = lines[0][1][1:]
    body = lines[1:]
    if not header:
        if not body:
            raise MeshLoadError(f"{path}: the OFF header has no vertex and face counts")
        header, body = body[0][1], body[1:]
    try:
        counts = [int(t) for t in header[:3]]
    except ValueError:
        raise MeshLoadError(f"{path}: the OFF counts must be integers, got {' '.join(header)!r}") from None
    if len(counts) < 2 or min(counts) < 0:
        raise MeshLoadError(f"{path}: the OFF header needs non-negative vertex and face counts, got {header!r}")
    nv, nf = counts[0], counts[1]
    if len(body) != nv + nf:
        raise MeshLoadError(
            f"{path}: the header announces {nv} vertices and {nf} faces ({nv + nf} lines) "
            f"but the file has {len(body)} data lines (malformed or truncated)"
        )
    for lineno, tokens in body[:nv]:
        if len(tokens) < 3 or not all(_number(t) for t in tokens[:3]):
            raise MeshLoadError(f"{path}:{lineno}: a vertex needs 3 numbers, got {' '.join(tokens)!r}")
    for lineno, tokens in body[nv:]:
        try:
            n = int(tokens[0])
            indices = [int(t) for t in tokens[1 : 1 + n]]
        except ValueError:
            raise MeshLoadError(f"{path}:{lineno}: a face must be 'n i1 ... in', got {' '.join(tokens)!r}") from None
        if n < 3 or len(indices) != n:
            raise MeshLoadError(f"{path}:{lineno}: a face needs n >= 3 indices after n, got {' '.join(tokens)!r}")
        bad = [i for i in indices if not 0 <= i < nv]
        if bad:
            raise MeshLoadError(f"{path}:{lineno}: vertex index {bad[0]} is out of range [0, {nv})")


def check_ascii_ply(data: bytes, path: Path) -> None:
    """Check an ASCII PLY body against its header: element counts, list lengths and vertex indices.

    Binary PLY files are left to trimesh (it refuses a body of the wrong length).

    Raises:
        MeshLoadError: a malformed header, a body with fewer or more values than announced, or an out-of-range
            face index.
    """
    end = data.find(b"end_header")
    if end < 0:
        raise MeshLoadError(f"{path}: the PLY header has no end_header line")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    if "format ascii" not in " ".join(" ".join(h.split()) for h in header):
        return
    elements: "list[tuple[str, int, list[tuple[str, bool]]]]" = []
    for line in header:
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0] == "element":
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise MeshLoadError(f"{path}: bad PLY header line {line!r}")
            elements.append((tokens[1], int(tokens[2]), []))
        elif tokens[0] == "property" and elements:
            is_list = len(tokens) >= 2 and tokens[1] == "list"
            if (is_list and len(tokens) != 5) or (not is_list and (len(tokens) != 3 or tokens[1] not in _PLY_SCALARS)):
                raise MeshLoadError(f"{path}: bad PLY header line {line!r}")
            elements[-1][2].append((tokens[-1], is_list))
    text = data[end + len(b"end_header") :].decode("ascii", errors="replace")
    try:
        _walk_ascii_ply(text.split(), elements, path)
    except MeshLoadError:
        lines = len([line for line in text.splitlines() if line.strip()])
        total = sum(count for _, count, _ in elements)
        if lines != total:
            announced = " and ".join(f"{count} {name}" for name, count, _ in elements)
            raise MeshLoadError(
                f"{path}: the PLY header announces {announced} elements ({total} lines) but the body has {lines} "
                "lines (malformed or truncated: the header's counts are wrong or lines are missing)"
            ) from None
        raise


def _walk_ascii_ply(body: "list[str]", elements: "list[tuple[str, int, list[tuple[str, bool]]]]", path: Path) -> None:
    """Consume the body's values element by element, as the header declares them."""
    pos = 0
    nv = next((count for name, count, _ in elements if name == "vertex"), None)
    for name, count, props in elements:
        for item in range(count):
            for prop, is_list in props:
                if pos >= len(body):
                    raise MeshLoadError(
                        f"{path}: the PLY header announces {count} {name} elements but the body ends in "
                        f"{name} {item} (malformed or truncated)"
                    )
                if not is_list:
                    if not _number(body[pos]):
                        raise MeshLoadError(f"{path}: {name} {item} property {prop} is not a number: {body[pos]!r}")
                    pos += 1
                    continue
                try:
                    n = int(body[pos])
                    values = [float(t) for t in body[pos + 1 : pos + 1 + n]]
                except ValueError:
                    raise MeshLoadError(f"{path}: {name} {item} list {prop} is not a list of numbers") from None
                if n < 0 or len(values) != n:
                    raise MeshLoadError(f"{path}: {name} {item} list {prop} is shorter than its count {n}")
                if name == "face" and nv is not None and prop in ("vertex_indices", "vertex_index"):
                    if n < 3:
                        raise MeshLoadError(f"{path}: face {item} has {n} vertex indices; a face needs at least 3")
                    bad = [v for v in values if not (v.is_integer() and 0 <= v < nv)]
                    if bad:
                        raise MeshLoadError(f"{path}: face {item} vertex index {bad[0]:g} is out of range [0, {nv})")
                pos += 1 + n
    if pos != len(body):
        raise MeshLoadError(
            f"{path}: the PLY body has {len(body) - pos} values more than its header announces "
            "(the header's element counts are wrong)"
        )
