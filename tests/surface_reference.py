"""An independent NumPy (float64) reference of textured / smooth-shaded rendering at fixed face assignment: the
pixel-centre convention, perspective-correct barycentrics, bilinear sampling with the UV origin at the bottom-left,
per-pixel Lambert shading. Written from the formulas in docs/TEXTURES.md, loop by loop, sharing no code with meshadv.
"""

from __future__ import annotations

import numpy as np


def pixel_centres(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """NDC ``(x, y)`` of every pixel centre, (H,W) each (row 0 at the top, +y up)."""
    cols = (2.0 * np.arange(w) + 1.0 - w) / w
    rows = (h - 1.0 - 2.0 * np.arange(h)) / h
    return np.meshgrid(cols, rows)


def barycentrics(screen: np.ndarray, tri: np.ndarray, x: float, y: float) -> np.ndarray:
    """Perspective-correct barycentrics of NDC point ``(x, y)`` in the face ``tri`` of ``screen`` (N,3) (x, y, z)."""
    p = screen[tri]
    (x0, y0), (x1, y1), (x2, y2) = p[0, :2], p[1, :2], p[2, :2]
    area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    w0 = ((x1 - x) * (y2 - y) - (y1 - y) * (x2 - x)) / area
    w1 = ((x2 - x) * (y0 - y) - (y2 - y) * (x0 - x)) / area
    w2 = 1.0 - w0 - w1
    q = np.array([w0, w1, w2]) / p[:, 2]
    return q / q.sum()


def bilinear(texture: np.ndarray, u: float, v: float, wrap: str) -> np.ndarray:
    """Bilinear sample of ``texture`` (Ht,Wt,C) at ``(u, v)``, origin at the bottom-left corner of the image."""
    ht, wt = texture.shape[:2]
    x, y = u * wt - 0.5, (1.0 - v) * ht - 0.5
    i0, j0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - i0, y - j0

    def texel(i: int, j: int) -> np.ndarray:
        if wrap == "repeat":
            return texture[j % ht, i % wt]
        return texture[min(max(j, 0), ht - 1), min(max(i, 0), wt - 1)]

    return (
        (1 - fx) * (1 - fy) * texel(i0, j0)
        + fx * (1 - fy) * texel(i0 + 1, j0)
        + (1 - fx) * fy * texel(i0, j0 + 1)
        + fx * fy * texel(i0 + 1, j0 + 1)
    )


def lambert(n: np.ndarray, directions: np.ndarray, colors: np.ndarray, ambient: np.ndarray) -> np.ndarray:
    """``ambient + sum_j c_j max(dot(d_j, n), 0)`` for one unit normal."""
    s = ambient.astype(np.float64).copy()
    for d, c in zip(directions, colors):
        s = s + c * max(float(np.dot(d / np.linalg.norm(d), n)), 0.0)
    return s


def render(
    screen: np.ndarray,
    faces: np.ndarray,
    face_index: np.ndarray,
    uvs: np.ndarray,
    uv_faces: np.ndarray,
    texture: np.ndarray,
    normals: np.ndarray,
    normal_faces: np.ndarray,
    flip: np.ndarray,
    lights: tuple[np.ndarray, np.ndarray, np.ndarray],
    background: np.ndarray,
    wrap: str = "repeat",
) -> np.ndarray:
    """(H,W,4) RGB + coverage of a smooth-shaded textured mesh with the given face assignment ``face_index`` (H,W).

    ``screen`` (N,3) are the projected vertices, ``normals`` (Nn,3) the vertex normals at ``normal_faces``, ``flip``
    (M,) +1 or -1 per face (its side toward the camera), ``lights`` ``(directions, colors, ambient)``.
    """
    h, w = face_index.shape
    xs, ys = pixel_centres(h, w)
    out = np.zeros((h, w, 4))
    for i in range(h):
        for j in range(w):
            f = face_index[i, j]
            if f < 0:
                out[i, j, :3] = background
                continue
            b = barycentrics(screen, faces[f], xs[i, j], ys[i, j])
            uv = b @ uvs[uv_faces[f]]
            albedo = bilinear(texture, uv[0], uv[1], wrap)
            n = flip[f] * (b @ normals[normal_faces[f]])
            n = n / np.linalg.norm(n)
            out[i, j, :3] = np.clip(albedo * lambert(n, *lights), 0.0, 1.0)
            out[i, j, 3] = 1.0
    return out


def nearest_faces(screen: np.ndarray, faces: np.ndarray, h: int, w: int, near: float, far: float) -> np.ndarray:
    """(H,W) brute-force face assignment: the nearest face whose triangle holds the pixel centre (-1 for none)."""
    xs, ys = pixel_centres(h, w)
    best = np.full((h, w), np.inf)
    index = np.full((h, w), -1)
    for f, tri in enumerate(faces):
        p = screen[tri]
        (x0, y0), (x1, y1), (x2, y2) = p[0, :2], p[1, :2], p[2, :2]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0:
            continue
        w0 = ((x1 - xs) * (y2 - ys) - (y1 - ys) * (x2 - xs)) / area
        w1 = ((x2 - xs) * (y0 - ys) - (y2 - ys) * (x0 - xs)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 > 0) & (w1 > 0) & (w2 > 0)
        z = 1.0 / (w0 / p[0, 2] + w1 / p[1, 2] + w2 / p[2, 2])
        nearer = inside & (z < best) & (z >= near) & (z <= far)
        best[nearer], index[nearer] = z[nearer], f
    return index
