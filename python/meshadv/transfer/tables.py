"""The paper's transfer tables (Table 3, targeted success per target class, Fig. 5's confusion matrices) and the
black-box tables, from transfer rows (:func:`~meshadv.transfer.results.load_transfer_rows`), as Markdown."""

from __future__ import annotations

from collections import defaultdict
from typing import Any, Optional, Sequence

from meshadv.util.markdown import markdown_table as _markdown_table

__all__ = [
    "BLACKBOX_ESTIMATION_COLUMNS",
    "BLACKBOX_MARGIN_COLUMNS",
    "BLACKBOX_OUTCOME_COLUMNS",
    "BLACKBOX_SCORE_COLUMNS",
    "BLACKBOX_SETTINGS_COLUMNS",
    "blackbox_report",
    "confusion_matrices",
    "markdown_confusion",
    "markdown_table",
    "per_target_table",
    "transfer_report",
    "transfer_table",
]


def _rate(values: Sequence[Optional[bool]]) -> Optional[float]:
    """The fraction of true values among those that are not None (None when all are None)."""
    vals = [bool(v) for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None


def transfer_table(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paper's Table 3: success rates per victim and attack type, untargeted and targeted.

    A targeted row counts for the targeted rate (top-1 in the target group); every row also counts for the untargeted
    rate through ``untargeted_meshadv`` / ``untargeted_mitsuba`` (top-1 not in the true group). Untargeted transfer
    to Mitsuba counts only on views whose benign mesh Mitsuba renders the victim classifies right
    (``benign_correct_mitsuba``, the benign control): a benign object the victim already gets wrong there is no
    transfer. Groups whose rows carry no control at all (older runs) fall back to every row, and say so with
    ``n_benign_mitsuba_checked`` 0.

    Returns:
        One dict per (victim, perturbation): ``n``, ``untargeted_meshadv``, ``untargeted_mitsuba`` (controlled, see
        above), ``targeted_meshadv``, ``targeted_mitsuba`` (rates in [0, 1] or None), ``n_benign_mitsuba_checked``
        (rows with the control) and ``n_benign_mitsuba_correct`` (rows whose benign Mitsuba render is right),
        ``untargeted_mitsuba_uncontrolled`` (the rate over every row, for comparison), ``n_benign_correct`` (rows
        whose benign meshadv render the sweep found right) and ``untargeted_mitsuba_benign_correct`` (the
        controlled rate over those rows only).
    """
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        groups[(row["victim"], row["perturbation"])].append(row)
    table = []
    for (victim, perturbation), items in sorted(groups.items()):
        targeted = [r for r in items if r.get("target")]
        checked = [r for r in items if r.get("benign_correct_mitsuba") is not None]
        counted = [r for r in items if r.get("benign_correct_mitsuba")] if checked else items
        table.append(
            {
                "victim": victim,
                "perturbation": perturbation,
                "n": len(items),
                "untargeted_meshadv": _rate([r.get("untargeted_meshadv") for r in items]),
                "untargeted_mitsuba": _rate([r.get("untargeted_mitsuba") for r in counted]),
                "targeted_meshadv": _rate([r.get("success_meshadv") for r in targeted]),
                "targeted_mitsuba": _rate([r.get("success_mitsuba") for r in targeted]),
                "n_benign_mitsuba_checked": len(checked),
                "n_benign_mitsuba_correct": sum(1 for r in checked if r.get("benign_correct_mitsuba")),
                "untargeted_mitsuba_uncontrolled": _rate([r.get("untargeted_mitsuba") for r in items]),
                "n_benign_correct": sum(1 for r in items if r.get("benign_correct")),
                "untargeted_mitsuba_benign_correct": _rate(
                    [r.get("untargeted_mitsuba") for r in counted if r.get("benign_correct")]
                ),
            }
        )
    return table


def per_target_table(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Targeted transfer success per victim and target class (meshadv vs Mitsuba)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        if row.get("target"):
            groups[(row["victim"], row["target"])].append(row)
    return [
        {
            "victim": victim,
            "target": target,
            "n": len(items),
            "targeted_meshadv": _rate([r.get("success_meshadv") for r in items]),
            "targeted_mitsuba": _rate([r.get("success_mitsuba") for r in items]),
        }
        for (victim, target), items in sorted(groups.items())
    ]


def confusion_matrices(
    rows: Sequence[dict[str, Any]], classes: Optional[Sequence[str]] = None, *, renderer: str = "mitsuba"
) -> dict[str, tuple[list[str], list[list[Optional[float]]]]]:
    """Targeted confusion matrices (the paper's Fig. 5): rate of success for each (true class, target class).

    Args:
        rows: transfer rows.
        classes: the class order (default: every class seen, sorted).
        renderer: ``"mitsuba"`` or ``"meshadv"`` (which success to count).

    Returns:
        ``{victim: (classes, matrix)}`` with ``matrix[i][j]`` the success rate of attacks on class ``i`` toward
        target ``j`` (None when there is no such attack).

    Raises:
        ValueError: unknown ``renderer``.
    """
    if renderer not in ("mitsuba", "meshadv"):
        raise ValueError(f"renderer must be 'mitsuba' or 'meshadv', got {renderer!r}")
    key = f"success_{renderer}"
    targeted = [r for r in rows if r.get("target")]
    names = list(classes) if classes is not None else sorted({r["true_class"] for r in targeted} |
                                                             {r["target"] for r in targeted})
    out = {}
    for victim in sorted({r["victim"] for r in targeted}):
        cells: dict[tuple[str, str], list[Any]] = defaultdict(list)
        for r in targeted:
            if r["victim"] == victim:
                cells[(r["true_class"], r["target"])].append(r.get(key))
        matrix = [[_rate(cells[(t, g)]) if (t, g) in cells else None for g in names] for t in names]
        out[victim] = (names, matrix)
    return out


def _fmt(value: Any) -> str:
    """A table cell: ``–`` for None, floats with two decimals (two significant digits when tiny)."""
    if value is None:
        return "–"
    if isinstance(value, float):
        if value != 0 and abs(value) < 0.005:
            return f"{value:.2g}"  # a learning rate or a weight such as 1e-05, not 0.00
        return f"{value:.2f}"
    return str(value)


def markdown_table(table: Sequence[dict[str, Any]], columns: Optional[Sequence[str]] = None) -> str:
    """Render a list of dicts as a GitHub-flavoured markdown table."""
    if not table:
        return "(no rows)\n"
    cols = list(columns) if columns is not None else list(table[0].keys())
    return _markdown_table(cols, [[_fmt(row.get(c)) for c in cols] for row in table]) + "\n"


def markdown_confusion(names: Sequence[str], matrix: Sequence[Sequence[Optional[float]]]) -> str:
    """Render a confusion matrix (rows: true class, columns: target class) as markdown."""
    rows = [[name, *(_fmt(v) for v in row)] for name, row in zip(names, matrix)]
    return _markdown_table(["true \\ target", *names], rows) + "\n"


#: Columns of the black-box tables: outcome, classifier margins, detector scores, attack settings, estimation errors.
BLACKBOX_OUTCOME_COLUMNS = ("case_id", "victim", "true_class", "target", "perturbation", "context", "success_meshadv",
                            "robust_rate_meshadv", "success_mitsuba_estimated", "success_mitsuba",
                            "benign_correct_mitsuba", "top1_adversarial_mitsuba")
BLACKBOX_MARGIN_COLUMNS = ("case_id", "margin_meshadv", "margin_mitsuba_estimated", "margin_mitsuba",
                           "margin_benign_mitsuba", "top1_meshadv", "top1_mitsuba_estimated")
BLACKBOX_SCORE_COLUMNS = ("case_id", "hide_score_meshadv", "hide_score_mitsuba_estimated",
                          "hide_score_adversarial_mitsuba", "hide_score_benign_mitsuba", "score_threshold")
BLACKBOX_SETTINGS_COLUMNS = ("case_id", "eot", "required_margin", "pixel_noise", "pixel_noise_on", "antialias",
                             "texture_smoothing", "object_scale", "method", "steps", "steps_run", "steps_to_success",
                             "lr", "lambda_perceptual", "color_rmse", "laplacian_pair_mean", "spp", "attack_time")
BLACKBOX_ESTIMATION_COLUMNS = ("case_id", "azimuth_error", "elevation_error", "distance_error", "mask_iou",
                               "light_fit", "light_fit_pixels", "light_rmse", "direction_error")


def blackbox_report(rows: Sequence[dict[str, Any]]) -> str:
    """The black-box section: outcome, margins (classifiers) or scores (detectors), settings, estimation errors.

    ``success_meshadv`` is meshadv's render of the final mesh on the estimated view, ``robust_rate_meshadv`` the
    fraction of fresh jittered estimated views on which it is adversarial, ``success_mitsuba_estimated`` Mitsuba's
    render under the *estimated* camera and lights (renderer mismatch only), ``success_mitsuba`` Mitsuba under the
    hidden parameters (the pipeline's result). A table is shown when some row has one of its columns, a column when
    some of the table's rows has it; a missing value shows as "–".
    """
    parts = ["\n### Black-box pipeline (estimated camera and lights)\n"]
    classifier = [r for r in rows if "hide_score_adversarial_mitsuba" not in r]
    detector = [r for r in rows if "hide_score_adversarial_mitsuba" in r]
    sections = (("Outcome", BLACKBOX_OUTCOME_COLUMNS, rows),
                ("Classifier margins (logits, > 0 = adversarial) and top-1 classes", BLACKBOX_MARGIN_COLUMNS,
                 classifier),
                ("Detector: best score of the hidden class (detected at >= score_threshold)", BLACKBOX_SCORE_COLUMNS,
                 detector),
                ("Attack settings and distortion", BLACKBOX_SETTINGS_COLUMNS, rows),
                ("Estimation errors (degrees; distance relative)", BLACKBOX_ESTIMATION_COLUMNS, rows))
    for title, cols, subset in sections:
        present = [c for c in cols if any(r.get(c) is not None for r in subset)]
        if len(present) <= 1:
            continue
        parts.append(f"\n#### {title}\n")
        parts.append(markdown_table(subset, present))
    return "\n".join(parts)


def transfer_report(rows: Sequence[dict[str, Any]]) -> str:
    """A markdown section with the transfer tables and confusion matrices of ``rows``."""
    controlled = [r for r in rows if r.get("kind", "controlled") == "controlled"]
    blackbox = [r for r in rows if r.get("kind") == "blackbox"]
    parts = ["## Transfer to Mitsuba 3\n"]
    if controlled:
        parts.append("### Controlled parameters (same camera and lights)\n")
        parts.append(markdown_table(transfer_table(controlled)))
        parts.append("\n#### Targeted success per target class\n")
        parts.append(markdown_table(per_target_table(controlled)))
        for victim, (names, matrix) in confusion_matrices(controlled).items():
            parts.append(f"\n#### Targeted confusion matrix, {victim} (Mitsuba)\n")
            parts.append(markdown_confusion(names, matrix))
    if blackbox:
        parts.append(blackbox_report(blackbox))
    return "\n".join(parts)
