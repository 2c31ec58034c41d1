"""The paper's figures (matplotlib, Agg backend, PNG).

- :func:`render_grid`: the classes x classes grid of renders (Fig. 2 style): row = benign class, column = target class,
  the diagonal shows the benign render (green frame, "benign"), target class names on top, failed attacks labelled
  "failed" in red, cells without a render say "no result" (or "source = target" on the diagonal) in grey; every
  title is wrapped to fit (:func:`grid_figure` draws it).
- :func:`flow_heatmaps`: per-vertex flow magnitude ``|v_adv - v|`` painted on the mesh, in the attack's view and in a
  canonical view (azimuth 135°, elevation 45°).
- :func:`flow_quiver`: a 3D quiver plot of the flow directions in the region around the most displaced vertex.
- :func:`curvature_scatter`: per-vertex flow magnitude against mean curvature, with Pearson and Spearman correlations.

Views use the contract's spherical camera (Y up, ``eye = (cos el sin az, sin el, -cos el cos az)``); matplotlib's Z-up
axes show world point ``(x, y, z)`` at ``(x, -z, y)`` with ``view_init(elev=el, azim=90 - az)``, which is the same view
direction (orthographic).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, AbstractSet, Any, Dict, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

__all__ = [
    "render_grid",
    "grid_figure",
    "flow_heatmaps",
    "flow_quiver",
    "curvature_scatter",
    "flow_magnitude",
    "flow_face_colors",
    "crop_to_content",
    "camera_eye",
    "mean_curvature_np",
    "CANONICAL_VIEW",
]

#: The canonical view of the flow figures: (azimuth, elevation) in degrees.
CANONICAL_VIEW = (135.0, 45.0)

PathLike = Union[str, Path]


def _pyplot() -> "ModuleType":
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig: Any, path: PathLike) -> Path:
    """Save ``fig`` to ``path`` at 100 dpi, atomically (:mod:`meshadv.util.atomic`; the folder is created), in the
    format its suffix names; returns the path."""
    from meshadv.util.atomic import atomic_path

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, suffix=out.suffix) as tmp:
        fig.savefig(tmp, dpi=100, format=out.suffix.lstrip(".") or "png")
    return out


def _check_mesh(vertices: np.ndarray, vertices_adv: np.ndarray, faces: np.ndarray) -> Tuple[np.ndarray, ...]:
    v = np.asarray(vertices, dtype=np.float64)
    va = np.asarray(vertices_adv, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
    if va.shape != v.shape:
        raise ValueError(f"vertices_adv must have the shape of vertices {v.shape}, got {va.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise ValueError(f"faces must be (M, 3) indices into the {len(v)} vertices")
    return v, va, f


def flow_magnitude(vertices: np.ndarray, vertices_adv: np.ndarray) -> np.ndarray:
    """Per-vertex flow magnitude ``|vertices_adv - vertices|`` ``(N,)``."""
    return np.linalg.norm(np.asarray(vertices_adv, np.float64) - np.asarray(vertices, np.float64), axis=1)


def flow_face_colors(vertices: np.ndarray, vertices_adv: np.ndarray, faces: np.ndarray,
                     cmap: str = "inferno") -> Tuple[np.ndarray, float]:
    """Face colours of the flow heatmap: each face's mean vertex flow magnitude on ``cmap`` over ``[0, max flow]``.

    Returns:
        ``(rgb (M, 3) in [0, 1], vmax)``: the colour scale runs from 0 (no flow) to ``vmax``, the largest vertex flow
        magnitude (1.0 when nothing moved).
    """
    v, va, f = _check_mesh(vertices, vertices_adv, faces)
    plt = _pyplot()
    mag = flow_magnitude(v, va)
    vmax = float(mag.max()) if len(mag) and mag.max() > 0 else 1.0
    rgb = plt.get_cmap(cmap)(np.clip(mag[f].mean(axis=1) / vmax, 0.0, 1.0))[:, :3]
    return rgb, vmax


def crop_to_content(image: np.ndarray, background: float = 1.0, margin: float = 0.08) -> np.ndarray:
    """``image (H, W, C)`` cropped to the box of pixels that differ from ``background``, plus ``margin`` of the box's
    size on each side (square, inside the image); the image itself when every pixel is background."""
    img = np.asarray(image)
    if img.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got shape {img.shape}")
    mask = (np.abs(img[..., :3].astype(np.float64) - background) > 1e-3).any(axis=-1)
    if not mask.any():
        return img
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    cy, cx = (rows[0] + rows[-1]) / 2, (cols[0] + cols[-1]) / 2
    half = max(rows[-1] - rows[0], cols[-1] - cols[0]) / 2 * (1 + 2 * margin) + 1
    h, w = img.shape[:2]
    half = min(half, h / 2, w / 2)
    top = int(round(min(max(cy - half, 0), h - 2 * half)))
    left = int(round(min(max(cx - half, 0), w - 2 * half)))
    size = int(round(2 * half))
    return img[top:top + size, left:left + size]


def camera_eye(view: Mapping[str, float]) -> np.ndarray:
    """The camera position of a view record (``distance``, ``azimuth``, ``elevation`` in degrees; the contract's
    spherical camera, Y up): ``d (cos el sin az, sin el, -cos el cos az)``."""
    d = float(view.get("distance", 2.5))
    az, el = math.radians(float(view["azimuth"])), math.radians(float(view["elevation"]))
    return d * np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


def _to_plot(points: np.ndarray) -> np.ndarray:
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def _set_view(ax: "Axes3D", azimuth: float, elevation: float, points: np.ndarray) -> None:
    """Point the 3-D axes ``ax`` at meshadv's (``azimuth``, ``elevation``) view of ``points``, equal scales."""
    ax.view_init(elev=elevation, azim=90.0 - azimuth)
    p = _to_plot(points)
    centre = (p.max(0) + p.min(0)) / 2
    half = float((p.max(0) - p.min(0)).max()) / 2 or 1.0
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()


#: Inches per grid cell, and the grid's label colours.
_CELL_IN = 1.6
_BENIGN, _FAILED, _EMPTY = "tab:green", "tab:red", "0.55"


def _wrap(text: str, width_in: float, fontsize: float) -> str:
    """``text`` wrapped to lines that fit ``width_in`` inches at ``fontsize`` points (0.6 em per character)."""
    chars = max(4, int(width_in * 72.0 / (0.6 * fontsize)))
    return "\n".join(textwrap.wrap(text, chars, break_long_words=True)) or text


def grid_figure(cells: Mapping[Tuple[str, str], PathLike], classes: Sequence[str], *, title: str = "",
                failed: AbstractSet[Tuple[str, str]] = frozenset()) -> Any:
    """The matplotlib figure of the classes x classes grid of renders (see :func:`render_grid`)."""
    if not classes:
        raise ValueError("classes must not be empty")
    plt = _pyplot()
    from PIL import Image

    n = len(classes)
    width = _CELL_IN * n + 0.8
    fig, axes = plt.subplots(n, n, figsize=(width, _CELL_IN * n + 1.0), squeeze=False, layout="constrained")
    for i, src in enumerate(classes):
        for j, tgt in enumerate(classes):
            ax = axes[i][j]
            ax.set_xticks([])
            ax.set_yticks([])
            img = cells.get((src, tgt))
            present = img is not None and Path(img).is_file()
            if present:
                ax.imshow(np.asarray(Image.open(img).convert("RGB")))
                for spine in ax.spines.values():
                    spine.set_visible(i == j)
                    spine.set_color(_BENIGN)
                    spine.set_linewidth(2)
                if i == j:
                    ax.set_xlabel("benign", fontsize=8, color=_BENIGN, labelpad=2)
                elif (src, tgt) in failed:
                    ax.set_xlabel("failed", fontsize=8, color=_FAILED, labelpad=2)
            else:  # no coloured frame: a grey note saying why the cell is empty
                note = "source = target\n(no benign render)" if i == j else "no result"
                ax.text(0.5, 0.5, note, ha="center", va="center", fontsize=8, color=_EMPTY, transform=ax.transAxes)
                for spine in ax.spines.values():
                    spine.set_color("0.85")
                    spine.set_linestyle((0, (3, 3)))
            if i == 0:
                ax.set_title(_wrap(tgt, _CELL_IN, 9), fontsize=9)
            if j == 0:
                ax.set_ylabel(_wrap(src, _CELL_IN, 9), fontsize=9)
    if title:
        fig.suptitle(_wrap(title, width - 0.2, 12), fontsize=12)
    return fig


def render_grid(cells: Mapping[Tuple[str, str], PathLike], classes: Sequence[str], path: PathLike, *,
                title: str = "", failed: AbstractSet[Tuple[str, str]] = frozenset()) -> Path:
    """Draw the classes x classes grid of renders.

    Args:
        cells: ``(source, target) -> PNG path``; ``(c, c)`` is the benign render of class ``c``. Missing cells (an
            attack that was not run or not saved) are marked "no result", a missing diagonal "source = target".
        classes: row / column order.
        path: output PNG.
        title: figure title (wrapped to the figure's width).
        failed: ``(source, target)`` cells whose attack did not succeed, labelled "failed".

    Returns:
        ``path``.

    Raises:
        ValueError: no classes.
    """
    plt = _pyplot()
    fig = grid_figure(cells, classes, title=title, failed=failed)
    out = _save_figure(fig, path)
    plt.close(fig)
    return out


def _render_flat(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray, view: Mapping[str, float],
                 size: int) -> Optional[np.ndarray]:
    """Render unlit face colours with meshadv's renderer from a view record; ``None`` when it is unavailable."""
    try:
        import torch

        from meshadv.render import ViewSet, render
    except ImportError:
        return None
    record = {"distance": float(view.get("distance", 2.5)), "azimuth": float(view["azimuth"]),
              "elevation": float(view["elevation"]), "tilt": float(view.get("tilt", 0.0)),
              "viewing_angle": float(view.get("viewing_angle", 30.0)), "light_directions": [[0.0, 0.0, -1.0]],
              "light_colors": [[0.0, 0.0, 0.0]], "ambient": [1.0, 1.0, 1.0]}
    try:
        views = ViewSet.from_records([record])
        out = render(torch.as_tensor(vertices, dtype=torch.float32), torch.as_tensor(faces, dtype=torch.int64),
                     torch.as_tensor(face_colors, dtype=torch.float32), views.camera, views.lights,
                     image_size=size, background=(1.0, 1.0, 1.0))
    except (ImportError, RuntimeError):  # native module missing
        return None
    return out.image[0].permute(1, 2, 0).detach().cpu().numpy()


def flow_heatmaps(vertices: np.ndarray, vertices_adv: np.ndarray, faces: np.ndarray, path: PathLike, *,
                  view: Union[Tuple[float, float], Mapping[str, float]],
                  canonical: Tuple[float, float] = CANONICAL_VIEW, title: str = "", renderer: str = "auto",
                  image_size: int = 320, crop: bool = True) -> Path:
    """Paint the per-vertex flow magnitude on the benign mesh, seen from the attack view and a canonical view.

    Args:
        vertices: benign vertices ``(N, 3)``; vertices_adv: adversarial vertices ``(N, 3)``; faces: ``(M, 3)``.
        path: output PNG.
        view: the rendered (attack) view: a ``ViewSet`` record (distance, azimuth, elevation, ...) or
            ``(azimuth, elevation)`` in degrees.
        canonical: ``(azimuth, elevation)`` of the canonical view (same distance as ``view``).
        title: figure title.
        renderer: ``"meshadv"`` renders with meshadv's rasterizer and the view's perspective camera, ``"matplotlib"``
            draws orthographic 3D polygons, ``"auto"`` uses meshadv's renderer when its native module is built.
        image_size: pixel size of the meshadv renders.
        crop: crop each meshadv render to the object (:func:`crop_to_content`), so a distant camera still shows it
            large; the colour scale (:func:`flow_face_colors`) runs from 0 to the largest vertex flow.

    Returns:
        ``path``.

    Raises:
        ValueError: bad shapes or renderer name; ImportError: ``renderer="meshadv"`` without the native module.
    """
    v, va, f = _check_mesh(vertices, vertices_adv, faces)
    if renderer not in ("auto", "meshadv", "matplotlib"):
        raise ValueError(f"renderer must be auto, meshadv or matplotlib, got {renderer!r}")
    record = dict(view) if isinstance(view, Mapping) else {"azimuth": float(view[0]), "elevation": float(view[1])}
    plt = _pyplot()
    from matplotlib import cm, colors
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    face_rgb, vmax = flow_face_colors(v, va, f)
    norm = colors.Normalize(vmin=0.0, vmax=vmax)
    cmap = plt.get_cmap("inferno")
    views = ((record, "rendered view"),
             ({**record, "azimuth": canonical[0], "elevation": canonical[1], "tilt": 0.0}, "canonical view"))
    fig = plt.figure(figsize=(9, 4.4))
    for k, (rec, label) in enumerate(views):
        az, el = float(rec["azimuth"]), float(rec["elevation"])
        image = None if renderer == "matplotlib" else _render_flat(v, f, face_rgb, rec, image_size)
        if image is None and renderer == "meshadv":
            raise ImportError("renderer='meshadv' needs the native module meshadv._raster (maturin develop)")
        if image is not None:
            ax = fig.add_subplot(1, 2, k + 1)
            ax.imshow(np.clip(crop_to_content(image) if crop else image, 0.0, 1.0))
            ax.set_axis_off()
        else:
            ax = fig.add_subplot(1, 2, k + 1, projection="3d")
            poly = Poly3DCollection(_to_plot(v[f]), facecolors=face_rgb, edgecolors="none")
            ax.add_collection3d(poly)
            _set_view(ax, az, el, v)
        ax.set_title(f"{label} (az {az:.0f}°, el {el:.0f}°)", fontsize=9)
    fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=fig.axes, shrink=0.7,
                 label="flow magnitude |v_adv - v| (mesh units)")
    if title:
        fig.suptitle(title)
    out = _save_figure(fig, path)
    plt.close(fig)
    return out


def flow_quiver(vertices: np.ndarray, vertices_adv: np.ndarray, faces: np.ndarray, path: PathLike, *,
                region: int = 150, view: Optional[Tuple[float, float]] = None, title: str = "") -> Path:
    """3D quiver plot of the flow directions of the ``region`` vertices nearest the most displaced vertex.

    Arrows are normalised to a common length (directions are what the plot shows) and coloured by magnitude; the
    region's triangles are drawn faintly for context. ``view`` = ``(azimuth, elevation)``; by default the camera looks
    at the region from outside (from the direction of the most displaced vertex).

    Returns:
        ``path``.
    """
    v, va, f = _check_mesh(vertices, vertices_adv, faces)
    if region < 1:
        raise ValueError(f"region must be >= 1, got {region}")
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    flow = va - v
    mag = np.linalg.norm(flow, axis=1)
    centre = v[int(np.argmax(mag))]
    idx = np.argsort(np.linalg.norm(v - centre, axis=1))[: min(region, len(v))]
    inside = np.zeros(len(v), dtype=bool)
    inside[idx] = True
    pts = v[idx]
    extent = float((pts.max(0) - pts.min(0)).max()) or 1.0
    direction = flow[idx] / np.maximum(mag[idx, None], 1e-12)
    fig = plt.figure(figsize=(6, 5.5))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    tri = f[inside[f].all(axis=1)]
    if len(tri):
        ax.add_collection3d(Poly3DCollection(_to_plot(v[tri]), facecolors=(0.7, 0.7, 0.7, 0.25),
                                             edgecolors=(0.4, 0.4, 0.4, 0.2), linewidths=0.3))
    p, d = _to_plot(pts), _to_plot(direction)
    ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], length=0.12 * extent,
              colors=plt.get_cmap("viridis")(mag[idx] / (mag[idx].max() or 1.0)), linewidths=0.8)
    if view is None:
        c = centre - v.mean(axis=0)
        c = c / (np.linalg.norm(c) or 1.0)
        view = (math.degrees(math.atan2(c[0], -c[2])), math.degrees(math.asin(float(np.clip(c[1], -1, 1)))))
    _set_view(ax, view[0], view[1], pts)
    ax.set_title(title or f"flow directions near the most displaced vertex ({len(idx)} vertices)", fontsize=9)
    out = _save_figure(fig, path)
    plt.close(fig)
    return out


def mean_curvature_np(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned discrete mean curvature per vertex: ``|L v| / 2`` with the cotangent Laplacian over barycentric areas.

    Used when ``meshadv.mesh.mean_curvature`` is not available. Isolated vertices get 0.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    n = len(v)
    lap = np.zeros_like(v)
    area = np.zeros(n)
    for k in range(3):
        i, j, o = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        e1, e2 = v[i] - v[o], v[j] - v[o]
        cross = np.linalg.norm(np.cross(e1, e2), axis=1)
        cot = np.einsum("ij,ij->i", e1, e2) / np.maximum(cross, 1e-12)
        w = (0.5 * cot)[:, None] * (v[j] - v[i])
        np.add.at(lap, i, w)
        np.add.at(lap, j, -w)
        np.add.at(area, o, cross / 6.0)
    return np.linalg.norm(lap, axis=1) / np.maximum(2.0 * area, 1e-12) * (area > 0)


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(a, b).statistic) if len(a) > 2 else math.nan


def curvature_scatter(vertices: np.ndarray, vertices_adv: np.ndarray, faces: np.ndarray, path: PathLike, *,
                      curvature: Optional[np.ndarray] = None, eye: Optional[np.ndarray] = None,
                      title: str = "") -> Tuple[Path, Dict[str, float]]:
    """Scatter per-vertex flow magnitude against mean curvature and report their correlation.

    The paper (Fig. 3) finds larger flow where the curvature is high and close to the camera; with ``eye`` (the camera
    position, :func:`camera_eye`) the points are coloured by their distance to the camera and the correlation of flow
    with that distance is reported too.

    Args:
        vertices, vertices_adv, faces: the benign and adversarial mesh.
        path: output PNG.
        curvature: per-vertex mean curvature ``(N,)``; default :func:`mean_curvature_np` of the benign mesh.
        eye: camera position ``(3,)`` of the attack view, or ``None``.
        title: figure title.

    Returns:
        ``(path, {"pearson": r, "spearman": rho, "vertices": N})`` (``nan`` when undefined, e.g. no flow at all), with
        ``eye``: also ``"spearman_camera_distance"`` (flow vs. distance to the camera; negative = more flow nearer).

    Raises:
        ValueError: bad shapes (``curvature`` not ``(N,)``, ``eye`` not ``(3,)``).
    """
    v, va, f = _check_mesh(vertices, vertices_adv, faces)
    curv = mean_curvature_np(v, f) if curvature is None else np.asarray(curvature, np.float64)
    if curv.shape != (len(v),):
        raise ValueError(f"curvature must have shape ({len(v)},), got {curv.shape}")
    if eye is not None:
        eye = np.asarray(eye, np.float64)
        if eye.shape != (3,) or not np.isfinite(eye).all():
            raise ValueError(f"eye must be a finite (3,) camera position, got shape {eye.shape}")
    mag = flow_magnitude(v, va)
    ok = np.isfinite(curv) & np.isfinite(mag)
    x, y = np.abs(curv[ok]), mag[ok]
    pearson = float(np.corrcoef(x, y)[0, 1]) if len(x) > 2 and x.std() > 0 and y.std() > 0 else math.nan
    spearman = _spearman(x, y) if x.std() > 0 and y.std() > 0 else math.nan
    stats: Dict[str, float] = {"pearson": pearson, "spearman": spearman, "vertices": int(len(x))}
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.2, 4.2))
    if eye is not None:
        dist = np.linalg.norm(v[ok] - eye, axis=1)
        stats["spearman_camera_distance"] = (_spearman(dist, y) if dist.std() > 0 and y.std() > 0 else math.nan)
        points = ax.scatter(x, y, s=4, alpha=0.6, c=dist, cmap="viridis_r")
        fig.colorbar(points, ax=ax, label="distance to the camera")
    else:
        ax.scatter(x, y, s=4, alpha=0.5)
    ax.set_xlabel("|mean curvature| (symmetric log scale)")
    positive = x[x > 0]
    if len(positive):
        ax.set_xscale("symlog", linthresh=float(np.percentile(positive, 5)) or 1e-6)
    ax.set_ylabel("perturbation magnitude")
    summary = f"Pearson r = {pearson:.3f}, Spearman ρ = {spearman:.3f}"
    if "spearman_camera_distance" in stats:
        summary += f"; flow vs camera distance ρ = {stats['spearman_camera_distance']:.3f}"
    ax.set_title(f"{title}\n{summary}" if title else summary, fontsize=9)
    fig.tight_layout()
    out = _save_figure(fig, path)
    plt.close(fig)
    return out, stats
