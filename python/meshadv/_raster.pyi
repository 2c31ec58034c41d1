"""Type stub of the native module ``meshadv._raster`` (Rust core, crates/pybridge).

All arrays must be C-contiguous numpy arrays; float arrays are float32 and index arrays int32 (``TypeError`` naming the
argument otherwise; arrays are borrowed read-only, never copied). Errors: ``ValueError`` (bad shape,
value, NaN/Inf, image size, near/far, all geometry behind the camera) and ``IndexError`` (face or face-index map entry
out of range), each naming the argument; ``MemoryError`` when an output buffer cannot be allocated; ``RuntimeError``
only for an internal error.
"""

import numpy as np
import numpy.typing as npt

MAX_IMAGE_SIZE: int
#: How many explicitly sized thread pools the native module keeps for reuse, per calling thread (a thread's pools
#: are its own, and their threads exit with it).
MAX_CACHED_POOLS: int

def rasterize_forward(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_attrs: npt.NDArray[np.float32],
    background: npt.NDArray[np.float32],
    height: int,
    width: int,
    near: float,
    far: float,
    cull_backfaces: bool,
    num_threads: int = 0,
    orthographic: bool = False,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32], npt.NDArray[np.float32]]:
    """Rasterize screen-space triangles with per-face attributes.

    Args:
        verts_screen: (B,N,3) ``(x_ndc, y_ndc, z_view)``.
        faces: (M,3) vertex indices.
        face_attrs: (B,M,C) per-face attributes.
        background: (C,) attribute of empty pixels.
        height: image height H in [1, 16384].
        width: image width W in [1, 16384].
        near: near clipping depth, ``0 <= near < far``.
        far: far clipping depth (written as depth on background).
        cull_backfaces: drop faces whose normal points away from the camera (counter-clockwise in y-up NDC).
        num_threads: rayon threads, 0 = default. Results do not depend on it.
        orthographic: interpolate z (not 1/z) linearly in screen space; faces behind the eye are kept.

    Returns:
        ``(image (B,H,W,C), face_index (B,H,W) int32 with -1 = background, depth (B,H,W) with far on background)``.
    """

def rasterize_backward(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_attrs: npt.NDArray[np.float32],
    background: npt.NDArray[np.float32],
    height: int,
    width: int,
    near: float,
    far: float,
    cull_backfaces: bool,
    face_index: npt.NDArray[np.int32],
    image: npt.NDArray[np.float32],
    grad_image: npt.NDArray[np.float32],
    num_threads: int = 0,
    orthographic: bool = False,
    vertex_grad: bool = True,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Backward of ``rasterize_forward`` (same leading arguments, plus its outputs and the image cotangent).

    Returns:
        ``(grad_verts_screen (B,N,3) with z = 0, grad_face_attrs (B,M,C))``. The vertex gradient is NMR's approximate
        rasterization gradient defined in docs/NMR_GRADIENT.md; the attribute gradient is exact.
    """

def flat_render_forward(
    verts: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_colors: npt.NDArray[np.float32],
    rotation: npt.NDArray[np.float32],
    eye: npt.NDArray[np.float32],
    scale: npt.NDArray[np.float32],
    light_directions: npt.NDArray[np.float32],
    light_colors: npt.NDArray[np.float32],
    ambient: npt.NDArray[np.float32],
    background: npt.NDArray[np.float32],
    batch: int,
    height: int,
    width: int,
    k: int,
    near: float,
    far: float,
    fill_back: bool,
    orthographic: bool,
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None, npt.NDArray[np.int32], npt.NDArray[np.float32],
           npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """The flat render (projection, Lambert shading, raster at ``k`` times ``height x width``, box filter).

    Args:
        verts: (Bv,N,3) world-space vertices; every batched input has batch 1 or ``batch``.
        faces: (M,3) vertex indices.
        face_colors: (Bc,M,3) reflectances.
        rotation: (Bk,3,3) world-to-view rotations (rows the view axes).
        eye: (Bk,3) eye positions.
        scale: (Bk,) ``tan(fov / 2)`` (perspective) or the half extent (orthographic), > 0.
        light_directions: (Bl,K,3) unit directions toward the lights.
        light_colors: (Bl,K,3) light intensities.
        ambient: (Bl,3) ambient intensities.
        background: (3,) RGB background.
        batch: views B.
        height: output height.
        width: output width.
        k: supersampling factor.
        near: near clipping depth.
        far: far clipping depth.
        fill_back: two-sided shading (normals flipped toward the camera); else back faces are culled.
        orthographic: orthographic projection.
        num_threads: rayon threads, 0 = default. Results do not depend on it.

    Returns:
        ``(image (B,H,W,4) RGB + coverage, full_image (B,kH,kW,4) or None when k = 1, face_index (B,kH,kW),
        depth (B,kH,kW), verts_screen (B,N,3), attrs (B,M,4))``.
    """

def flat_render_backward(
    verts: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_colors: npt.NDArray[np.float32],
    rotation: npt.NDArray[np.float32],
    eye: npt.NDArray[np.float32],
    scale: npt.NDArray[np.float32],
    light_directions: npt.NDArray[np.float32],
    light_colors: npt.NDArray[np.float32],
    ambient: npt.NDArray[np.float32],
    background: npt.NDArray[np.float32],
    batch: int,
    height: int,
    width: int,
    k: int,
    near: float,
    far: float,
    fill_back: bool,
    orthographic: bool,
    verts_screen: npt.NDArray[np.float32],
    attrs: npt.NDArray[np.float32],
    face_index: npt.NDArray[np.int32],
    image: npt.NDArray[np.float32],
    grad_image: npt.NDArray[np.float32] | None,
    grad_alpha: npt.NDArray[np.float32] | None,
    edge_weight: float = 1.0,
    need_verts: bool = True,
    sweep_radius: int | None = None,
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], ...]:
    """Backward of :func:`flat_render_forward` (its arguments, its ``verts_screen``, ``attrs``, ``face_index`` and
    supersampled image, and the cotangents of the (B,3,H,W) image and (B,1,H,W) coverage, any strides).

    Returns:
        The gradients of ``(verts, face_colors, rotation, eye, scale, light_directions, light_colors, ambient)``,
        each shaped as its input. ``edge_weight`` scales the rasterization gradient of the screen-space vertices;
        ``need_verts=False`` skips the vertex and camera gradients (zeros); ``sweep_radius`` as in
        :func:`rasterize_backward`.
    """

def box_downsample(image: npt.NDArray[np.float32], k: int, num_threads: int = 0) -> npt.NDArray[np.float32]:
    """The ``k x k`` block averages of a supersampled image: (B,kH,kW,C) -> (B,H,W,C), the bits of
    ``F.avg_pool2d(x, k, k)`` on the channels-first view (samples added row by row, then divided by ``k*k``).

    Raises ``ValueError`` naming ``k`` (not in [1, 64]) or ``image`` (a side not divisible by ``k``).
    """

def box_spread(grad: npt.NDArray[np.float32], k: int, num_threads: int = 0) -> npt.NDArray[np.float32]:
    """The adjoint of :func:`box_downsample`: (B,H,W,C) -> (B,kH,kW,C), each value divided by ``k*k`` and given to
    every sample of its block (the bits of ``avg_pool2d``'s backward).

    Raises ``ValueError`` naming ``k`` (not in [1, 64]).
    """

def raycast(
    verts_view: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    height: int,
    width: int,
    viewing_angle: float = 30.0,
    near: float = 0.1,
    far: float = 100.0,
    orthographic: bool = False,
    ortho_scale: float = 1.0,
    cull_backfaces: bool = False,
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float32]]:
    """Exact BVH ray cast of view-space triangles (B,N,3), one primary ray per pixel centre.

    Returns:
        ``(face_index (B,H,W) int32, depth (B,H,W) float32)``, as the rasterizer on the projected vertices except on
        exact ties and within rounding of an edge.
    """

def render_full(
    verts_world: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_colors: npt.NDArray[np.float32],
    height: int,
    width: int,
    distance: float,
    azimuth: float,
    elevation: float,
    tilt: float = 0.0,
    viewing_angle: float = 30.0,
    near: float = 0.1,
    far: float = 100.0,
    orthographic: bool = False,
    ortho_scale: float = 1.0,
    light_directions: npt.NDArray[np.float32] | None = None,
    light_colors: npt.NDArray[np.float32] | None = None,
    ambient: npt.NDArray[np.float32] | None = None,
    background: npt.NDArray[np.float32] | None = None,
    fill_back: bool = True,
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.int32]]:
    """Full forward render of one view in Rust (spherical camera, Lambert shading, rasterization).

    Args:
        verts_world: (N,3) world vertices. faces: (M,3). face_colors: (M,3) reflectances.
        light_directions, light_colors: (K,3) each, both or neither (default: one light 0.5 toward +Y).
        ambient: (3,) (default 0.5). background: (3,) (default white).
        fill_back: two-sided with normals flipped toward the camera; False culls back faces.

    Returns:
        ``(image (H,W,3), alpha (H,W), depth (H,W), face_index (H,W))``.
    """

def pixel_weights(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    near: float,
    far: float,
    orthographic: bool = False,
    num_threads: int = 0,
) -> npt.NDArray[np.float32]:
    """Perspective-correct barycentric weights (B,H,W,3) of the face drawn at each pixel of ``face_index`` (B,H,W),
    0 on background (docs/TEXTURES.md)."""

def pixel_weights_backward(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    grad_weights: npt.NDArray[np.float32],
    near: float,
    far: float,
    orthographic: bool = False,
    num_threads: int = 0,
) -> npt.NDArray[np.float32]:
    """Backward of ``pixel_weights``: the exact gradient (B,N,3) to ``verts_screen`` (x, y and z)."""

def interpolate(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    weights: npt.NDArray[np.float32],
    corners: npt.NDArray[np.int32],
    values: npt.NDArray[np.float32],
    num_threads: int = 0,
) -> npt.NDArray[np.float32]:
    """Per-corner attributes ``values`` (Bv,A,K) with rows ``corners`` (M,3) interpolated with ``weights``
    (B,H,W,3): (B,H,W,K), 0 on background."""

def interpolate_backward(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    weights: npt.NDArray[np.float32],
    corners: npt.NDArray[np.int32],
    values: npt.NDArray[np.float32],
    grad: npt.NDArray[np.float32],
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Backward of ``interpolate``: ``(grad_values (Bv,A,K), grad_weights (B,H,W,3))``."""

class UvTexturePlanes:
    """The drawn faces' UV planes of one ``sample_uv_texture`` call, for its backward (opaque)."""

def sample_uv_texture(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    corners: npt.NDArray[np.int32],
    uvs: npt.NDArray[np.float32],
    texture: npt.NDArray[np.float32],
    near: float,
    far: float,
    orthographic: bool = False,
    wrap: str = "repeat",
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], UvTexturePlanes]:
    """The texture (Bt,Ht,Wt,C) sampled (bilinear) at each pixel's perspective-correct UV, interpolated from ``uvs``
    (Bv,T,2) with rows ``corners`` (M,3): ``(image (B,H,W,C), 0 on background; the UV planes for the backward)``;
    ``wrap`` is ``"repeat"`` or ``"clamp"`` (docs/TEXTURES.md)."""

def sample_uv_texture_backward(
    planes: UvTexturePlanes,
    face_index: npt.NDArray[np.int32],
    texture: npt.NDArray[np.float32],
    grad: npt.NDArray[np.float32],
    wrap: str = "repeat",
    num_threads: int = 0,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Backward of ``sample_uv_texture`` with the ``planes`` it returned and its ``face_index`` and ``texture``:
    ``(grad_texture (Bt,Ht,Wt,C), grad_uvs (Bv,T,2), grad_verts_screen (B,N,3))``, the last at fixed face
    assignment."""

def image_vertex_backward(
    verts_screen: npt.NDArray[np.float32],
    faces: npt.NDArray[np.int32],
    face_index: npt.NDArray[np.int32],
    image: npt.NDArray[np.float32],
    grad_image: npt.NDArray[np.float32],
    near: float,
    far: float,
    cull_backfaces: bool,
    orthographic: bool = False,
    num_threads: int = 0,
) -> npt.NDArray[np.float32]:
    """NMR's vertex gradient (B,N,3), z = 0, of an image (B,H,W,C) with per-pixel colours drawn with ``face_index``,
    for its cotangent ``grad_image``; on an image drawn with per-face colours it is ``rasterize_backward``'s."""
