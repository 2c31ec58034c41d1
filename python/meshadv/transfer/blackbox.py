"""The black-box transfer pipeline: attack a Mitsuba "photo" whose camera and lights are unknown.

The paper's pipeline (:func:`blackbox_classifier`, :func:`blackbox_detector`): a "photo" is rendered by Mitsuba
under hidden parameters (:class:`~meshadv.transfer.hidden.HiddenScene`); the camera is estimated from the object's
mask, the lights from the masked image (:func:`~meshadv.transfer.photo.estimate_parameters`); the attack runs in
meshadv with random jitter of the estimates at every step (:mod:`meshadv.transfer.robust`); the adversarial mesh is
re-rendered by Mitsuba under the hidden parameters and tested, and, as a diagnostic, under the estimates
(:mod:`meshadv.transfer.compositing`). Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`).

The pipelines live in :mod:`~meshadv.transfer.classifier_pipeline` and :mod:`~meshadv.transfer.detector_pipeline`,
what they share in :mod:`meshadv.transfer._pipeline`; this module re-exports them with the steps' public names
(``HiddenScene``, ``Estimation``, ``estimate_parameters``, ``estimated_view_spec``, ``composite``,
``occlusion_mask``, ``detection_scores``).
"""

from __future__ import annotations

from meshadv.transfer._scoring import detection_scores
from meshadv.transfer.classifier_pipeline import blackbox_classifier
from meshadv.transfer.compositing import composite, estimated_view_spec
from meshadv.transfer.detector_pipeline import blackbox_detector
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.objects import occlusion_mask
from meshadv.transfer.photo import Estimation, estimate_parameters

__all__ = [
    "Estimation",
    "HiddenScene",
    "blackbox_classifier",
    "blackbox_detector",
    "composite",
    "detection_scores",
    "estimate_parameters",
    "estimated_view_spec",
    "occlusion_mask",
]
