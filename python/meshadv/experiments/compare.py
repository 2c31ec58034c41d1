"""Our tables beside the paper's: Table 1, Table 2, Table 3 and the human study, with the shortfalls spelled out.

The paper's numbers come from :mod:`meshadv.experiments.paper` (cited there). Ours come from
:func:`meshadv.experiments.tables.table1` / :func:`~meshadv.experiments.tables.table2` and the ``transfer`` rows of the
results database (:func:`meshadv.transfer.results.load_transfer_rows`).

A *shortfall* compares our row in the paper's measure with the most lenient of the paper's models: a success rate
below the paper's lowest, or a mean distance above the paper's highest, is reported with the gap (percentage points,
or how many times the paper's distance).
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any, Dict, List, Optional, Sequence, Tuple

from meshadv.experiments import paper
from meshadv.experiments.tables import PAPER_WORST, Table1Row, Table2Row, above_text

__all__ = ["table1_beside_paper", "table1_shortfalls", "table1_tail", "table2_beside_paper", "table3_beside_paper",
           "untargeted_by_target", "human_study_line", "paper_comparison"]

_CASES = ("best", "average", "worst")


def _pct(value: Optional[float]) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{100.0 * value:.1f}%"


def _num(value: Optional[float]) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.3g}"


def table1_beside_paper(rows: Sequence[Table1Row]) -> str:
    """Markdown: per perturbation type, our Table 1 rows (every measure) followed by the paper's rows.

    The last three columns are the tail of our successful attacks' distances (90th percentile, largest, share above
    the paper's largest worst-case distance, :data:`~meshadv.experiments.tables.PAPER_WORST`); the paper reports
    means only, so its rows show ``–`` there.

    Args:
        rows: our Table 1 rows.

    Returns:
        The table (``_no results_`` when ``rows`` is empty).
    """
    if not rows:
        return "_no results_\n"
    lines = ["| source | type | distance | best: dist | best: success | average: dist | average: success | "
             "worst: dist | worst: success | successes: p90 dist | successes: max dist | "
             "successes above the paper's worst |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for perturbation in sorted({r.perturbation for r in rows}):
        for r in (r for r in rows if r.perturbation == perturbation):
            mark = " (paper's measure)" if r.paper_measure else ""
            cells = " | ".join(f"{_num(getattr(r, c).distance)} | {_pct(getattr(r, c).success_rate)}" for c in _CASES)
            tail = ("– | – | –" if r.tail is None
                    else f"{_num(r.tail.p90)} | {_num(r.tail.max)} | {above_text(r.tail)}")
            lines.append(f"| ours: {r.victim} | {perturbation} | {r.distance_name}{mark} | {cells} | {tail} |")
        for p in (p for p in paper.TABLE1 if p.perturbation == perturbation):
            measure = "laplacian (pair-mean scale)" if perturbation == "shape" else "color_rmse"
            cells = " | ".join(f"{_num(getattr(p, c)[0])} | {_pct(getattr(p, c)[1])}" for c in _CASES)
            lines.append(f"| paper: {p.model} | {perturbation} | {measure} | {cells} | – | – | – |")
    return "\n".join(lines) + "\n"


def table1_tail(rows: Sequence[Table1Row]) -> List[str]:
    """One sentence per our row in the paper's measure with successful attacks above the paper's largest worst-case
    distance: how many, and how far the largest goes.

    Args:
        rows: our Table 1 rows (rows not in the paper's measure, or without tail statistics, are ignored).

    Returns:
        Sentences; empty when no successful attack exceeds it.
    """
    out = []
    for r in rows:
        t = r.tail
        if not r.paper_measure or t is None or t.above_n == 0 or math.isnan(t.threshold):
            continue
        out.append(f"{r.victim} {r.perturbation}: {t.above_n} of {t.n} successful attacks ({_pct(t.above)}) have "
                   f"{r.distance_name} above {_num(t.threshold)}, the paper's largest worst-case distance; the "
                   f"largest is {_num(t.max)} ({t.max / t.threshold:.1f}x), the 90th percentile {_num(t.p90)}.")
    return out


def table1_shortfalls(rows: Sequence[Table1Row]) -> List[str]:
    """One sentence per (our row in the paper's measure, case) that falls short of every model of the paper.

    Args:
        rows: our Table 1 rows (rows not in the paper's measure are ignored).

    Returns:
        Sentences; empty when we match or beat the paper everywhere.
    """
    out = []
    for r in rows:
        theirs = [p for p in paper.TABLE1 if p.perturbation == r.perturbation]
        if not r.paper_measure or not theirs:
            continue
        for case in _CASES:
            ours = getattr(r, case)
            low_success = min(getattr(p, case)[1] for p in theirs)
            high_dist = max(getattr(p, case)[0] for p in theirs)
            if ours.success_rate < low_success:
                out.append(f"{r.victim} {r.perturbation}, {case} case: success {_pct(ours.success_rate)} against the "
                           f"paper's {_pct(low_success)} or more ({100.0 * (low_success - ours.success_rate):.1f} "
                           "points short).")
            if not math.isnan(ours.distance) and ours.distance > high_dist:
                out.append(f"{r.victim} {r.perturbation}, {case} case: {r.distance_name} {_num(ours.distance)} "
                           f"against the paper's {_num(high_dist)} or less ({ours.distance / high_dist:.1f}x).")
    return out


def table2_beside_paper(rows: Sequence[Table2Row]) -> str:
    """Markdown: per victim and perturbation type, success on unseen views as ``ours (paper)`` per view count and range.

    The paper's Table 2 is for shape attacks; texture cells show ``–`` for the paper.

    Args:
        rows: our Table 2 rows.
    """
    if not rows:
        return "_no multi-view results_\n"
    ranges = list(paper.TABLE2_AZIMUTH_RANGES)
    for r in rows:
        if r.azimuth_range not in ranges:
            ranges.append(r.azimuth_range)
    counts = sorted(set(paper.TABLE2_VIEW_COUNTS) | {r.num_views for r in rows})
    head = " | ".join(f"{a:g}°–{b:g}°" for a, b in ranges)
    parts = []
    for victim, perturbation in sorted({(r.victim, r.perturbation) for r in rows}):
        ours = {(r.num_views, r.azimuth_range): r for r in rows if (r.victim, r.perturbation) == (victim, perturbation)}
        lines = [f"**{victim}, {perturbation}**: success on unseen views, ours (paper, shape attacks); "
                 "attacks per cell in brackets", "", f"| attack views | {head} |",
                 "|---|" + "---|" * len(ranges)]
        for n in counts:
            cells = []
            for rng in ranges:
                mine = ours.get((n, rng))
                theirs = paper.TABLE2.get((n, rng)) if perturbation == "shape" else None
                text = "–" if mine is None else f"{_pct(mine.unseen_success)} [{mine.attacks}]"
                cells.append(f"{text} ({_pct(theirs)})")
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)


def untargeted_by_target(transfer_rows: Sequence[Dict[str, Any]]) -> Dict[str, Dict[str, Tuple[float, int]]]:
    """Untargeted Mitsuba success of shape attacks per victim and target class (the paper's Table 3 layout).

    Args:
        transfer_rows: rows of the ``transfer`` table (controlled kind); rows with an ``error`` or no
            ``untargeted_mitsuba`` verdict are left out.

    Returns:
        ``{victim: {target: (rate, n), ..., "average": (mean of the per-target rates, n)}}``.
    """
    groups: Dict[str, Dict[str, List[bool]]] = defaultdict(lambda: defaultdict(list))
    for row in transfer_rows:
        if row.get("kind", "controlled") != "controlled" or row.get("perturbation") != "shape":
            continue
        if not row.get("target") or row.get("untargeted_mitsuba") is None or row.get("error"):
            continue
        groups[row["victim"]][row["target"]].append(bool(row["untargeted_mitsuba"]))
    out: Dict[str, Dict[str, Tuple[float, int]]] = {}
    for victim, by_target in sorted(groups.items()):
        rates = {t: (sum(v) / len(v), len(v)) for t, v in by_target.items()}
        mean = sum(r for r, _ in rates.values()) / len(rates)
        rates["average"] = (mean, sum(n for _, n in rates.values()))
        out[victim] = rates
    return out


def table3_beside_paper(transfer_rows: Sequence[Dict[str, Any]]) -> str:
    """Markdown: untargeted transfer of shape attacks to Mitsuba per target class, ours (with counts) and the paper's.

    Args:
        transfer_rows: rows of the ``transfer`` table.
    """
    ours = untargeted_by_target(transfer_rows)
    classes = list(paper.TABLE3_CLASSES)
    for rates in ours.values():
        classes += [c for c in rates if c not in classes and c != "average"]
    cols = classes + ["average"]
    lines = ["| source | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for victim, rates in ours.items():
        cells = [f"{_pct(rates[c][0])} ({rates[c][1]})" if c in rates else "–" for c in cols]
        lines.append(f"| ours: {victim} | " + " | ".join(cells) + " |")
    for model, rates in paper.TABLE3.items():
        lines.append(f"| paper: {model} | " + " | ".join(_pct(rates.get(c)) for c in cols) + " |")
    if not ours:
        lines.append("| ours | " + " | ".join("–" for _ in cols) + " |")
    return "\n".join(lines) + "\n"


def human_study_line() -> str:
    """The paper's human-study result, one sentence."""
    h = paper.HUMAN_STUDY
    return (f"Human study (paper): {100 * h['true_class_rate']:.2f} ± {100 * h['std']:.2f}% of {h['answers']} "
            f"two-alternative answers from {h['participants']} participants chose the true class over the target.")


def paper_comparison(t1: Sequence[Table1Row], t2: Sequence[Table2Row],
                     transfer_rows: Sequence[Dict[str, Any]] = ()) -> str:
    """The whole side-by-side section (Markdown): Tables 1-3 beside the paper's, shortfalls, human study.

    Args:
        t1: our Table 1 rows (the paper's protocol: benign-correct instances).
        t2: our Table 2 rows.
        transfer_rows: our ``transfer`` rows (controlled; may be empty).
    """
    lines = ["## Beside the paper", "", f"The paper's numbers: {paper.CITATION}. Its victims are DenseNet-121 and "
             "Inception-v3; ours are named per row. The shape distance comparable with the paper is "
             "laplacian_pair_mean (the Eq. 4 sum divided by the 2E vertex-neighbour pairs); laplacian_sum is the "
             "literal Eq. 4 sum.", "", "### Table 1", "", table1_beside_paper(t1),
             "The columns that compare with the paper are the best / average / worst distance and success of our rows "
             "in the paper's measure. The last three columns are the tail of our successful attacks' distances, "
             "which the paper does not report (it gives means only): the 90th percentile, the largest, and the share "
             "above the paper's largest worst-case distance (" + ", ".join(
                 f"{k} {_num(v)}" for k, v in PAPER_WORST.items()) + "), itself a mean over the paper's instances, "
             "so some of the paper's own attacks lie above it too.", ""]
    tail = table1_tail(t1)
    if tail:
        lines += ["Successful attacks above the paper's worst case (the distortion tail):", ""]
        lines += [f"- {s}" for s in tail] + [""]
    short = table1_shortfalls(t1)
    if short:
        lines += ["Where we fall short of the paper (against the most lenient of its two models):", ""]
        lines += [f"- {s}" for s in short] + [""]
    elif t1:
        lines += ["Every case in the paper's measures matches or beats the paper's weaker model.", ""]
    lines += ["### Table 2 (multi-view shape attacks, unseen views)", "", table2_beside_paper(t2),
              "### Table 3 (untargeted transfer of successful shape attacks to Mitsuba, per target class)", "",
              table3_beside_paper(transfer_rows),
              f"Counts in brackets are attacks. Targeted transfer: the paper reports that {paper.TARGETED_TRANSFER}; "
              "ours is in the confusion matrices of the transfer section.", "", human_study_line(), ""]
    return "\n".join(lines)
