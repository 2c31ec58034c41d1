"""Estimate the camera and the lighting of a photo of a known object (the paper's black-box pipeline, steps 1-2).

1. Camera (:mod:`~meshadv.transfer.camera_estimate`): minimise ``||R_mask(S; P) - M||^2`` over azimuth, elevation
   and distance through meshadv's differentiable silhouette (NMR gradients), from several starting views (a coarse
   grid scored without gradients, the best few refined with Adam, all in one batch).
2. Lights (:mod:`~meshadv.transfer.light_estimate`): with the camera fixed, minimise the masked image error
   ``||M * (R(S; P, L) - I')||^2`` over ``K`` directional lights (direction, colour) and an ambient colour.

Both need torch and :mod:`meshadv.render`. This module re-exports their public names.
"""

from __future__ import annotations

from meshadv.transfer.camera_estimate import CameraEstimate, estimate_camera
from meshadv.transfer.light_estimate import LightEstimate, estimate_lights, light_errors, masked_rmse

__all__ = ["CameraEstimate", "LightEstimate", "estimate_camera", "estimate_lights", "light_errors", "masked_rmse"]
