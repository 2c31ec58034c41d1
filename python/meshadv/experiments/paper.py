"""The numbers MeshAdv reports, for side-by-side comparison with ours (data only).

Source: Xiao et al., "MeshAdv: Adversarial Meshes for Visual Recognition", CVPR 2019: Table 1 (targeted attacks on
PASCAL3D+ renderings), Table 2 (multi-view shape attacks, success on 20 unseen views), Table 3 (transfer of shape
attacks to Mitsuba under the same camera and lights, untargeted) and the human perceptual study.
Rates are fractions in ``[0, 1]``.

Conventions: the paper's shape distance is the Laplacian loss of the flow (Eq. 4); its magnitudes match the mean over
(vertex, neighbour) pairs, ``laplacian_pair_mean`` in :mod:`meshadv.attacks.distances`, not the literal sum. Its
texture distance is the face-colour RMSE, ``color_rmse``. Victims: DenseNet-121 and Inception-v3.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Tuple

__all__ = [
    "CITATION",
    "PaperTable1Row",
    "TABLE1",
    "TABLE2",
    "TABLE2_VIEW_COUNTS",
    "TABLE2_AZIMUTH_RANGES",
    "TABLE3",
    "TABLE3_CLASSES",
    "HUMAN_STUDY",
    "TARGETED_TRANSFER",
]

#: How the report cites the source of these numbers.
CITATION = "Xiao et al., \"MeshAdv: Adversarial Meshes for Visual Recognition\", CVPR 2019"


@dataclass(frozen=True)
class PaperTable1Row:
    """One row of the paper's Table 1: a perturbation type and a model, with best / average / worst case.

    Attributes:
        perturbation: ``"shape"`` or ``"texture"``. model: the paper's victim.
        best, average, worst: ``(distance, success rate)`` of each case.
    """

    perturbation: str
    model: str
    best: Tuple[float, float]
    average: Tuple[float, float]
    worst: Tuple[float, float]


#: The paper's Table 1 (test accuracy on the pristine renderings: 100% for both models).
TABLE1: Tuple[PaperTable1Row, ...] = (
    PaperTable1Row("shape", "DenseNet", (8.4e-5, 1.000), (1.8e-4, 1.000), (3.0e-4, 1.000)),
    PaperTable1Row("shape", "Inception-v3", (4.8e-5, 1.000), (1.2e-4, 0.998), (2.3e-4, 0.986)),
    PaperTable1Row("texture", "DenseNet", (3.8e-3, 1.000), (1.1e-2, 0.998), (2.6e-2, 0.986)),
    PaperTable1Row("texture", "Inception-v3", (3.7e-3, 1.000), (1.3e-2, 1.000), (3.2e-2, 1.000)),
)

#: Table 2's victim-set sizes (attack views) and azimuth ranges (degrees).
TABLE2_VIEW_COUNTS: Tuple[int, ...] = (5, 10, 15)
TABLE2_AZIMUTH_RANGES: Tuple[Tuple[float, float], ...] = ((45.0, 60.0), (35.0, 70.0), (15.0, 75.0))

#: The paper's Table 2: targeted success of multi-view shape attacks on 20 unseen views of the same azimuth range,
#: keyed by (attack views, azimuth range).
TABLE2: Dict[Tuple[int, Tuple[float, float]], float] = {
    (5, (45.0, 60.0)): 0.67, (5, (35.0, 70.0)): 0.45, (5, (15.0, 75.0)): 0.28,
    (10, (45.0, 60.0)): 0.73, (10, (35.0, 70.0)): 0.58, (10, (15.0, 75.0)): 0.38,
    (15, (45.0, 60.0)): 0.79, (15, (35.0, 70.0)): 0.74, (15, (15.0, 75.0)): 0.48,
}

#: Table 3's columns: the adversarial target classes.
TABLE3_CLASSES: Tuple[str, ...] = ("aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa")

#: The paper's Table 3: untargeted success in Mitsuba of the shape attacks, per model and target class, and the
#: average over targets (key ``"average"``).
TABLE3: Dict[str, Dict[str, float]] = {
    "DenseNet": {"aeroplane": 0.652, "bicycle": 0.691, "boat": 0.667, "bottle": 0.630, "chair": 0.371,
                 "diningtable": 0.703, "sofa": 0.479, "average": 0.598},
    "Inception-v3": {"aeroplane": 0.671, "bicycle": 0.833, "boat": 0.396, "bottle": 0.769, "chair": 0.321,
                     "diningtable": 0.750, "sofa": 0.523, "average": 0.609},
}

#: What the paper says of targeted transfer to Mitsuba (Fig. 5 shows confusion matrices, without numbers in the text).
TARGETED_TRANSFER = "targeted attacks barely transfer (Fig. 5 confusion matrices)"

#: The human perceptual study (2AFC on Amazon Mechanical Turk, true class vs. target class, image shown for 2 s):
#: the fraction of answers that chose the true class (mean and standard deviation), answers and participants.
HUMAN_STUDY = {"true_class_rate": 0.9929, "std": 0.0196, "answers": 3820, "participants": 49}
