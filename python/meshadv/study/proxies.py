"""Automatic perceptual proxies: SSIM and PSNR of each attack's benign vs. adversarial render (scikit-image).

They give "imperceptible" a number before anyone is asked: SSIM (Wang et al. 2004; 1 = identical) and PSNR in dB
(infinite when identical), per view, averaged over a job's views. :func:`proxy_section` writes ``proxies.csv`` (one
row per attack) and returns the Markdown section the sweep report shows (means per victim and perturbation type, over
successful attacks and over all attacks). A job whose renders are not on this machine keeps the values of the
``proxies.csv`` already in the report folder (a report re-run from the database alone), so they need no
regeneration.
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

__all__ = ["ProxyRow", "image_proxies", "attack_proxies", "proxy_section", "read_proxies"]


@dataclass(frozen=True)
class ProxyRow:
    """The proxies of one attack job.

    Attributes:
        job_id, victim, perturbation, source_class, target: the job (``victim`` with ``[protocol]`` for an extra
            protocol's jobs, as the report's tables name them).
        success: whether the attack succeeded. distance: its distance (Laplacian or colour RMSE).
        ssim: mean SSIM over views. psnr: mean PSNR over views in dB (``inf`` when the renders are identical).
        views: number of view pairs compared.
    """

    job_id: str
    victim: str
    perturbation: str
    source_class: str
    target: str
    success: bool
    distance: Optional[float]
    ssim: float
    psnr: float
    views: int


def _load_rgb(path: Union[str, Path]) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as img:
        return np.asarray(img.convert("RGB"))


ImageLike = Union[str, Path, np.ndarray]


def image_proxies(benign: ImageLike, adversarial: ImageLike) -> Tuple[float, float]:
    """SSIM and PSNR (dB) of two 8-bit RGB images (arrays ``(H, W, 3)`` or PNG paths).

    Args:
        benign: the reference image.
        adversarial: the compared image, same size.

    Returns:
        ``(ssim, psnr)``; PSNR is ``inf`` for identical images.

    Raises:
        ValueError: the images differ in size or are smaller than 7 x 7 pixels (SSIM's window).

    Example:
        >>> a = np.zeros((16, 16, 3), np.uint8)
        >>> image_proxies(a, a)
        (1.0, inf)
    """
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    a = benign if isinstance(benign, np.ndarray) else _load_rgb(benign)
    b = adversarial if isinstance(adversarial, np.ndarray) else _load_rgb(adversarial)
    if a.shape != b.shape:
        raise ValueError(f"benign and adversarial images must have the same shape, got {a.shape} and {b.shape}")
    if a.ndim != 3 or min(a.shape[:2]) < 7:
        raise ValueError(f"images must be (H, W, 3) with H, W >= 7, got {a.shape}")
    if np.array_equal(a, b):
        return 1.0, math.inf
    ssim = float(structural_similarity(a, b, channel_axis=-1, data_range=255))
    psnr = float(peak_signal_noise_ratio(a, b, data_range=255))
    return ssim, psnr


def _images(row: Any, key: str) -> List[Path]:
    names = (row.record or {}).get("artifacts", {}).get(key) or []
    names = names if isinstance(names, list) else [names]
    return [Path(row.out_dir) / n for n in names] if row.out_dir else []


def attack_proxies(rows: Sequence[Any], previous: Optional[Mapping[str, Tuple[float, float, int]]] = None,
                   ) -> Tuple[List[ProxyRow], int]:
    """SSIM and PSNR of every attack job whose benign and adversarial renders are on disk, or in ``previous``.

    Args:
        rows: ``done`` job rows (:class:`~meshadv.experiments.store.JobRow`).
        previous: job id -> ``(ssim, psnr, views)`` measured before (:func:`read_proxies`), used for a job whose
            renders are not on disk.

    Returns:
        ``(proxies, missing)``: one :class:`ProxyRow` per attack with renders or earlier values, and the number of
        attacks (done, not skipped) with neither.
    """
    from meshadv.experiments.tables import victim_label

    out: List[ProxyRow] = []
    missing = 0
    for row in rows:
        rec = row.record or {}
        if row.state != "done" or rec.get("skipped") or "target" not in row.spec:
            continue
        pairs = [(a, b) for a, b in zip(_images(row, "benign_images"), _images(row, "adversarial_images"))
                 if a.is_file() and b.is_file()]
        if pairs:
            values = [image_proxies(a, b) for a, b in pairs]
            measured = (float(np.mean([v[0] for v in values])), float(np.mean([v[1] for v in values])), len(values))
        elif previous and row.job_id in previous:
            measured = previous[row.job_id]
        else:
            missing += 1
            continue
        out.append(ProxyRow(
            job_id=row.job_id, victim=victim_label(row.spec) if "victim" in row.spec else "",
            perturbation=str(row.spec.get("perturbation", "")), source_class=str(row.spec.get("source_class", "")),
            target=str(row.spec["target"]), success=bool(rec.get("success")),
            distance=None if rec.get("distance") is None else float(rec["distance"]),
            ssim=measured[0], psnr=measured[1], views=measured[2]))
    return out, missing


def read_proxies(path: Union[str, Path]) -> Dict[str, Tuple[float, float, int]]:
    """Job id -> ``(ssim, psnr, views)`` of a ``proxies.csv`` written by :func:`proxy_section` (``{}`` when there is
    no such file)."""
    path = Path(path)
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as fh:
        return {r["job_id"]: (float(r["ssim"]), float(r["psnr"]), int(r["views"])) for r in csv.DictReader(fh)}


def _mean(values: List[float]) -> str:
    if not values:
        return "–"
    m = float(np.mean(values))
    return "∞" if math.isinf(m) else f"{m:.4g}"


def proxy_section(rows: Sequence[Any], out_dir: Union[str, Path]) -> str:
    """Write ``proxies.csv`` into ``out_dir`` and return the report's Markdown section (``""`` without attacks); an
    attack whose renders are not on disk keeps its values from the ``proxies.csv`` already there.

    Args:
        rows: ``done`` job rows of a sweep.
        out_dir: the report folder (exists).

    Returns:
        The Markdown section.
    """
    from meshadv.util.atomic import write_bytes_atomic

    proxies, missing = attack_proxies(rows, read_proxies(Path(out_dir) / "proxies.csv"))
    if not proxies:
        return ""
    buf = io.StringIO()
    fields = list(asdict(proxies[0]))
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for p in proxies:
        writer.writerow(asdict(p))
    write_bytes_atomic(Path(out_dir) / "proxies.csv", buf.getvalue().encode("utf-8"))
    groups: Dict[Tuple[str, str], List[ProxyRow]] = defaultdict(list)
    for p in proxies:
        groups[(p.victim, p.perturbation)].append(p)
    lines = ["## Perceptual proxies: SSIM and PSNR of benign vs. adversarial renders", "",
             "Per attack, mean over its views (scikit-image; SSIM 1 and PSNR ∞ mean identical renders). Every attack: "
             "[proxies.csv](proxies.csv). A human 2AFC study of the same renders: `meshadv study export`.", "",
             "| victim | type | successful attacks | SSIM (successful) | PSNR dB (successful) | all attacks | "
             "SSIM (all) | PSNR dB (all) |", "|---|---|---|---|---|---|---|---|"]
    for (victim, perturbation), group in sorted(groups.items()):
        ok = [p for p in group if p.success]
        lines.append(f"| {victim} | {perturbation} | {len(ok)} | {_mean([p.ssim for p in ok])} | "
                     f"{_mean([p.psnr for p in ok])} | {len(group)} | {_mean([p.ssim for p in group])} | "
                     f"{_mean([p.psnr for p in group])} |")
    if missing:
        lines += ["", f"{missing} attacks have no renders on disk and are not included."]
    return "\n".join(lines) + "\n"
