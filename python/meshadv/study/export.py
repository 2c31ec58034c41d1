"""Write the study as a self-contained static folder: one HTML page, its JavaScript and CSS, the images, the plan.

Folder layout::

    index.html      the page (open it from disk, or put the folder on any static web host)
    study.js        the 2AFC protocol (fixation, exposure, two answers, progress, downloads, optional POST)
    study.css       its style
    plan.js         ``window.STUDY_PLAN = {...}``: the plan as a script, because browsers do not let a page opened
                    from ``file://`` read a JSON file
    plan.json       the same plan as JSON (for people and for ``meshadv study analyze``)
    images/<image_id>.png

Participant ``N`` opens ``index.html?participant=N``; other query parameters (e.g. a crowdsourcing site's worker id)
are saved with the answers.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Dict, List, Optional, Union

from meshadv.study.plan import StudyPlan, make_plan
from meshadv.study.selection import Stimulus, select_stimuli
from meshadv.util.paths import relative_path

__all__ = ["ExportedStudy", "export_study", "write_study_folder", "WEB_FILES"]

#: The page's static files, shipped in ``meshadv/study/web``.
WEB_FILES = ("index.html", "study.js", "study.css")


@dataclass(frozen=True)
class ExportedStudy:
    """What :func:`export_study` wrote.

    Attributes:
        out_dir: the study folder. stimuli: the images. plan: the participants' trials.
    """

    out_dir: Path
    stimuli: List[Stimulus]
    plan: StudyPlan

    def counts(self) -> Dict[str, int]:
        """Number of images of each kind."""
        out = {"adversarial": 0, "control": 0, "attention": 0}
        for s in self.stimuli:
            out[s.kind] += 1
        return out


def _check_settings(exposure_ms: float, fixation_ms: float, image_px: int, post_mode: str,
                    post_url: Optional[str]) -> None:
    if not exposure_ms > 0:
        raise ValueError(f"exposure_ms must be > 0, got {exposure_ms}")
    if fixation_ms < 0:
        raise ValueError(f"fixation_ms must be >= 0, got {fixation_ms}")
    if image_px < 1:
        raise ValueError(f"image_px must be >= 1, got {image_px}")
    if post_mode not in ("json", "form"):
        raise ValueError(f"post_mode must be 'json' or 'form', got {post_mode!r}")
    if post_url is not None and not post_url.startswith(("http://", "https://")):
        raise ValueError(f"post_url must be an http:// or https:// URL, got {post_url!r}")


def write_study_folder(out_dir: Union[str, Path], stimuli: List[Stimulus], plan: StudyPlan,
                       settings: Dict[str, Any], *, overwrite: bool = False) -> Path:
    """Write the folder (staged next to ``out_dir``, then renamed into place, so it is complete or absent).

    Args:
        out_dir: the study folder.
        stimuli: the images (their ``source`` files are copied).
        plan: the plan (its ids must be the stimuli's).
        settings: the page settings (``exposure_ms``, ``fixation_ms``, ``image_px``, ``post_url``, ``post_mode``,
            ``study_id``).
        overwrite: replace an existing folder.

    Returns:
        ``out_dir``.

    Raises:
        FileExistsError: ``out_dir`` exists, is not empty and ``overwrite`` is false.
    """
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"output folder {out} exists and is not empty (pass overwrite / --overwrite)")
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=str(out.parent)))
    previous: Optional[Path] = None
    try:
        (staging / "images").mkdir()
        table: Dict[str, Dict[str, Any]] = {}
        for s in stimuli:
            name = f"{s.image_id}.png"
            shutil.copyfile(s.source, staging / "images" / name)
            table[s.image_id] = {**s.to_record(), "file": name}
        record = {**plan.to_record(), "settings": {**plan.settings, **settings}, "stimuli": table}
        text = json.dumps(record, indent=1, sort_keys=True)
        (staging / "plan.json").write_text(text + "\n", encoding="utf-8")
        (staging / "plan.js").write_text("window.STUDY_PLAN = " + text + ";\n", encoding="utf-8")
        web = resources.files("meshadv.study") / "web"
        for name in WEB_FILES:
            (staging / name).write_bytes((web / name).read_bytes())
        if out.exists():  # the old folder is moved aside (one rename), not deleted, until the new one is in place
            previous = Path(tempfile.mkdtemp(prefix=f".{out.name}.previous-", dir=str(out.parent))) / out.name
            out.rename(previous)
        staging.rename(out)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
        if previous is not None:
            if out.exists():
                shutil.rmtree(previous.parent, ignore_errors=True)
            else:  # interrupted between the two renames: the old study comes back
                previous.rename(out)
                previous.parent.rmdir()
    return out


def export_study(db_path: Union[str, Path], out_dir: Union[str, Path], *, per_image: int = 5, max_trials: int = 50,
                 seed: int = 0, controls: int = 0, attention_checks: int = 0, max_images: Optional[int] = None,
                 post_url: Optional[str] = None,
                 post_mode: str = "json", exposure_ms: float = 2000.0, fixation_ms: float = 500.0,
                 image_px: int = 299, overwrite: bool = False) -> ExportedStudy:
    """Pick the study's images from a sweep's results database and write the study folder.

    Args:
        db_path: the results database (``meshadv sweep``).
        out_dir: the study folder.
        per_image: answers each image gets (the paper: 5).
        max_trials: most trials per participant, attention checks included (the paper: 50).
        seed: seed of the control sample, the assignment, the trial order and the answers' order.
        controls: number of benign controls.
        attention_checks: attention checks each participant sees.
        max_images: show at most this many adversarial images (a seeded sample); ``None``: every successful attack.
        post_url: where the page POSTs the answers at the end (``None``: only downloads).
        post_mode: ``"json"`` (a ``fetch`` with the JSON answers as body) or ``"form"`` (a form POST with fields
            ``answers`` and ``assignmentId``, as crowdsourcing sites' external-submit URLs expect).
        exposure_ms: how long each image is shown (the paper: 2000).
        fixation_ms: how long the fixation cross is shown before it.
        image_px: the image's side on screen in CSS pixels.
        overwrite: replace an existing folder.

    Returns:
        An :class:`ExportedStudy`.

    Raises:
        FileNotFoundError: no database. FileExistsError: ``out_dir`` is not empty.
        ValueError: a bad argument (named) or no successful attack.
        MissingRenderError: a render can neither be found nor made again.
    """
    _check_settings(exposure_ms, fixation_ms, image_px, post_mode, post_url)
    with tempfile.TemporaryDirectory(prefix="meshadv-study-") as work:
        stimuli = select_stimuli(db_path, work, controls=controls, attention_checks=attention_checks, seed=seed,
                                 max_images=max_images)
        study_ids = [s.image_id for s in stimuli if s.kind != "attention"]
        checks = [s.image_id for s in stimuli if s.kind == "attention"]
        plan = make_plan(study_ids, per_image=per_image, max_trials=max_trials, attention_ids=checks, seed=seed)
        settings = {"max_images": max_images, "exposure_ms": float(exposure_ms), "fixation_ms": float(fixation_ms),
                    "image_px": int(image_px),
                    "post_url": post_url, "post_mode": post_mode, "study_id": f"{Path(db_path).stem}-s{seed}",
                    "database": relative_path(db_path, out_dir)}
        path = write_study_folder(out_dir, stimuli, plan, settings, overwrite=overwrite)
    return ExportedStudy(path, stimuli, plan)
