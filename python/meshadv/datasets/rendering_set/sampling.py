"""The sampling law of the rendering set: its options, the per-candidate seed and one candidate's camera and lights."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from meshadv.render.views import frame_distance
from meshadv.util.spherical import spherical_direction

__all__ = ["RenderingSetConfig", "candidate_seed", "sample_view", "sampling_config"]


@dataclass(frozen=True)
class RenderingSetConfig:
    """Sampling and rendering options of the rendering set (all ranges are inclusive-low, uniform).

    Attributes:
        azimuth_range: degrees.
        elevation_range: degrees.
        fill_range: the mesh's widest projected half-extent as a fraction of the half image (NDC), in ``(0, 1]``.
        light_max_angle: maximum angle in degrees between the light direction and the view direction.
        light_range: grey intensity of the directional light.
        ambient_range: grey ambient intensity.
        viewing_angle: camera field of view in degrees.
        background: RGB background colour.
        image_size: rendered image size (square).
        antialias: supersampling factor of the renderer.
        z_up: the meshes are Z-up (PASCAL3D+) and are rotated to the renderer's Y-up on load.
        detector_threshold: minimum detection score for a detector victim to count the class as found.
        max_candidates_per_class: stop a class (``exhausted``) after this many candidates; ``0`` = 50 x per_class.
            Not part of the set's identity: resuming with a larger budget continues the exhausted classes and yields
            the same set as a run that had the larger budget from the start.
    """

    azimuth_range: tuple[float, float] = (0.0, 360.0)
    elevation_range: tuple[float, float] = (0.0, 90.0)
    fill_range: tuple[float, float] = (0.7, 0.95)
    light_max_angle: float = 60.0
    light_range: tuple[float, float] = (0.35, 0.55)
    ambient_range: tuple[float, float] = (0.45, 0.65)
    viewing_angle: float = 30.0
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    image_size: int = 224
    antialias: int = 2
    z_up: bool = True
    detector_threshold: float = 0.3
    max_candidates_per_class: int = 0

    def __post_init__(self) -> None:
        for name in ("azimuth_range", "elevation_range", "fill_range", "light_range", "ambient_range"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        lo, hi = self.elevation_range
        if lo < -90 or hi > 90:
            raise ValueError(f"elevation_range must lie in [-90, 90], got {(lo, hi)}")
        lo, hi = self.fill_range
        if lo <= 0 or hi > 1:
            raise ValueError(f"fill_range must lie in (0, 1], got {(lo, hi)}")
        if not 0 <= self.light_max_angle <= 90:
            raise ValueError(f"light_max_angle must be in [0, 90], got {self.light_max_angle}")
        if not 0 < self.viewing_angle < 180:
            raise ValueError(f"viewing_angle must be in (0, 180), got {self.viewing_angle}")
        if self.image_size < 8:
            raise ValueError(f"image_size must be >= 8, got {self.image_size}")
        if len(self.background) != 3:
            raise ValueError(f"background must have 3 values, got {self.background}")
        if self.max_candidates_per_class < 0:
            raise ValueError(f"max_candidates_per_class must be >= 0, got {self.max_candidates_per_class}")

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists)."""
        return json.loads(json.dumps(asdict(self)))


def sampling_config(doc: Mapping[str, Any]) -> RenderingSetConfig:
    """The :class:`RenderingSetConfig` a rendering-set document was built with."""
    raw = dict(doc["config"]["sampling"])
    return RenderingSetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})


def candidate_seed(seed: int, class_index: int, candidate: int) -> int:
    """The 32-bit seed of candidate ``candidate`` of class number ``class_index`` (independent of batching)."""
    return int(np.random.SeedSequence([int(seed), int(class_index), int(candidate)]).generate_state(1)[0])


def sample_view(rng: np.random.Generator, vertices: np.ndarray, config: RenderingSetConfig) -> dict[str, Any]:
    """Draw one camera + lighting configuration as a ViewSet record (see :mod:`meshadv.datasets.rendering_set`).

    Args:
        rng: the candidate's generator.
        vertices: ``(N, 3)`` world-space vertices of the (normalised, centred) mesh, for framing.
        config: sampling ranges.

    Returns:
        A record accepted by :meth:`meshadv.render.ViewSet.from_records`.
    """
    azimuth = float(rng.uniform(*config.azimuth_range))
    elevation = float(rng.uniform(*config.elevation_range))
    fill = float(rng.uniform(*config.fill_range))
    to_eye = np.array(spherical_direction(azimuth, elevation))
    distance = frame_distance(vertices, to_eye, fill, config.viewing_angle)
    light_dir = _light_direction_near(to_eye, config.light_max_angle, rng)
    light = float(rng.uniform(*config.light_range))
    ambient = float(rng.uniform(*config.ambient_range))
    return {
        "distance": distance,
        "azimuth": azimuth,
        "elevation": elevation,
        "tilt": 0.0,
        "viewing_angle": float(config.viewing_angle),
        "near": 0.1,
        "far": 100.0,
        "orthographic": False,
        "ortho_scale": 1.0,
        "light_directions": [light_dir.tolist()],
        "light_colors": [[light, light, light]],
        "ambient": [ambient, ambient, ambient],
    }


def _light_direction_near(to_eye: np.ndarray, max_angle: float, rng: np.random.Generator) -> np.ndarray:
    """A direction uniform on the spherical cap of half-angle ``max_angle`` degrees around the unit ``to_eye``."""
    cos_max = math.cos(math.radians(max_angle))
    cos_t = float(rng.uniform(cos_max, 1.0))
    phi = float(rng.uniform(0.0, 2.0 * math.pi))
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    helper = np.array([0.0, 1.0, 0.0]) if abs(to_eye[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, to_eye)
    u /= np.linalg.norm(u)
    v = np.cross(to_eye, u)
    return cos_t * to_eye + sin_t * (math.cos(phi) * u + math.sin(phi) * v)
