"""Perceptibility of adversarial meshes: measures a person would agree with, and the cap an attack must stay inside.

* :mod:`~meshadv.perceptibility.geometry` -- vertex moves relative to the bounding-box diagonal, area-weighted
  changes of the face normals (degrees) and of the face colours, length-weighted strain of the edges;
* :mod:`~meshadv.perceptibility.images` -- SSIM between benign and adversarial renders;
* :mod:`~meshadv.perceptibility.held_out` -- the held-out views (between and away from an attack's views);
* :mod:`~meshadv.perceptibility.measures` -- all of them for an attack's meshes;
* :mod:`~meshadv.perceptibility.cap` -- :class:`PerceptibilityCap` and :data:`DEFAULT_CAP`.
"""

from meshadv.perceptibility.cap import DEFAULT_CAP, NO_CAP, PerceptibilityCap, as_cap, recommended_cap, step_measures
from meshadv.perceptibility.geometry import (
    PERCENTILE,
    SURFACE_MEASURES,
    color_changes,
    edge_strains,
    normal_changes,
    surface_measures,
    vertex_moves,
)
from meshadv.perceptibility.images import render_ssim
from meshadv.perceptibility.measures import MEASURE_DESCRIPTIONS, perceptibility_measures
from meshadv.perceptibility.held_out import held_out_views

__all__ = [
    "DEFAULT_CAP", "NO_CAP", "PerceptibilityCap", "as_cap", "recommended_cap", "step_measures",
    "PERCENTILE", "SURFACE_MEASURES", "color_changes", "edge_strains", "normal_changes",
    "surface_measures", "vertex_moves",
    "render_ssim", "MEASURE_DESCRIPTIONS", "perceptibility_measures", "held_out_views",
]
