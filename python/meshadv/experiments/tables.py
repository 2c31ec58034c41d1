"""The paper's tables from sweep results: Table 1 (best / average / worst case) and Table 2 (multi-view robustness).

**Table 1 cases** follow Carlini & Wagner ("Towards Evaluating the Robustness of Neural Networks", S&P 2017, sec. V),
which MeshAdv adopts. An *instance* is one benign input: (victim, perturbation type, mesh, rendering configuration,
seed); it is attacked towards every target class (the other classes of the sweep).

- **Best case**: the easiest target of each instance. The instance counts as a success when *any* target succeeds; its
  distance is the *smallest* distance among its successful targets.
- **Worst case**: the hardest target. The instance counts as a success only when *every* target succeeds (a failed
  target is the hardest of all); its distance is the *largest* distance among its targets.
- **Average case**: a target drawn uniformly at random; in expectation the success rate is the mean over instances of
  the fraction of their targets that succeed, and the distance is the mean over every successful (instance, target)
  attack.

Success rates are fractions of instances; a case's mean distance is taken over its successful instances (successful
attacks for the average case), as in C&W. Each measure of :data:`DISTANCE_NAMES` gets its own row (same success
columns): shape attacks in both conventions of the Laplacian loss (``laplacian_pair_mean``, the one comparable with
the paper, and the literal Eq. 4 ``laplacian_sum``; see :mod:`meshadv.attacks.distances`), texture attacks by the
face-colour RMSE; after them the perceptibility measures of :mod:`meshadv.perceptibility` (largest and
95th-percentile vertex move, face-normal change, face-colour change, and ``dssim_held_out_max``, the structural
dissimilarity ``(1 - SSIM) / 2`` of the least similar held-out view), for records that hold them. Instances
attacked towards fewer targets than the others of their group (a job still missing or crashed) are left out of the
best and worst cases and counted as ``incomplete``; crashed jobs are not results and never count as failed attacks.

**Tail columns** (a mean or median hides a tail of broken meshes): over every successful attack of a
row (the average case's population), the median, the 90th percentile (:func:`percentile`, linear interpolation
between order statistics) and the largest distance, and, for the paper's measure, the share of successful attacks
whose distance exceeds :data:`PAPER_WORST` (the largest worst-case distance of the paper's Table 1, a mean over its
instances: shape 3.0e-4 per-pair mean, texture 3.2e-2 colour RMSE). The paper reports means only, so these columns
have no counterpart there; the ones that compare with the paper are the three cases' distance and success columns
of the rows in the paper's measure.

**Success by class pair** (:func:`pair_success`): Table 1's attacks counted per (source class, target class), so
that a shortfall can be traced to the pairs it comes from (the paper reports only the pooled cases).

**Table 2**: for each (victim, type, number of attack views, azimuth range), the fraction of attacks that succeed on
their attack views and the mean success rate on the unseen views of the same range.
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from dataclasses import asdict, dataclass, fields
from typing import Any, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from meshadv.attacks.distances import PAPER_COMPARABLE, read_distance
from meshadv.experiments import paper
from meshadv.experiments.retries import protocol_label

__all__ = [
    "AttackRow",
    "CaseStats",
    "PairSuccess",
    "PAPER_WORST",
    "TailStats",
    "Table1Row",
    "Table2Row",
    "attack_rows",
    "format_cell",
    "single_view_results",
    "labelled_by_protocol",
    "pair_success",
    "pair_success_markdown",
    "table1",
    "table2",
    "to_markdown",
    "to_csv",
    "victim_label",
    "DISTANCE_NAMES",
    "percentile",
    "tail_stats",
    "above_text",
    "tail_cells",
]

#: The distances reported per perturbation type, the one comparable with the paper first, then the measures a person
#: would agree with (:mod:`meshadv.perceptibility`; rows only for records that hold them).
DISTANCE_NAMES: Dict[str, Tuple[str, ...]] = {
    "shape": ("laplacian_pair_mean", "laplacian_sum", "max_displacement", "p95_displacement",
              "normal_change_mean_deg", "normal_change_p95_deg", "edge_strain_p95", "edge_strain_max",
              "dssim_held_out_max"),
    "texture": ("color_rmse", "color_change_p95", "dssim_held_out_max"),
}
#: The measures every record can give (the others are left out of the rows of records that lack them).
_ALWAYS_READ = ("laplacian_pair_mean", "laplacian_sum", "color_rmse", "distance")

#: The paper's largest worst-case distance per perturbation type, in its measure (:data:`PAPER_COMPARABLE`): the
#: largest of its two models' Table 1 worst cases (shape 3.0e-4, DenseNet; texture 3.2e-2, Inception-v3).
PAPER_WORST: Dict[str, float] = {p: max(r.worst[0] for r in paper.TABLE1 if r.perturbation == p)
                                 for p in sorted({r.perturbation for r in paper.TABLE1})}


@dataclass(frozen=True)
class AttackRow:
    """One finished single-view attack, flattened for the tables.

    Attributes:
        victim, perturbation: the group. instance: hashable key of the benign input (mesh, configuration, seed).
        source, target: classes. success: the target was reached. distance: the value of ``measure`` (or
        ``None``). measure: the distance's name (a key of :func:`meshadv.attacks.distances.mesh_distances`).
    """

    victim: str
    perturbation: str
    instance: Tuple[Any, ...]
    source: str
    target: str
    success: bool
    distance: Optional[float]
    measure: str = "distance"


@dataclass(frozen=True)
class CaseStats:
    """Success rate and mean distance of one case (``distance`` is ``nan`` when nothing succeeded)."""

    success_rate: float
    distance: float
    n: int


@dataclass(frozen=True)
class TailStats:
    """The distance's distribution over ``n`` successful attacks (``nan`` statistics when ``n == 0``).

    Attributes:
        n: successful attacks with a distance. median, p90, max: their median, 90th percentile (:func:`percentile`)
            and largest distance. threshold: the distance counted as too large (``nan``: none, e.g. a measure that
            is not the paper's). above: the fraction of the ``n`` above ``threshold`` (``nan`` without one or
            without attacks). above_n: how many.
    """

    n: int
    median: float
    p90: float
    max: float
    threshold: float
    above: float
    above_n: int


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile of ``values`` by linear interpolation between order statistics
    (:func:`numpy.percentile`'s default ``"linear"`` method: rank ``(n - 1) q / 100``); ``nan`` for no values.

    Raises:
        ValueError: ``q`` outside ``[0, 100]`` or a ``nan`` among ``values``.
    """
    if not 0.0 <= q <= 100.0:
        raise ValueError(f"q must be in [0, 100], got {q}")
    vals = np.asarray(values, dtype=np.float64)
    if np.isnan(vals).any():
        raise ValueError("values must not contain nan")
    return float(np.percentile(vals, q)) if vals.size else math.nan


def tail_stats(values: Sequence[float], threshold: Optional[float] = None) -> TailStats:
    """:class:`TailStats` of ``values`` (the distances of successful attacks); ``threshold`` ``None``: no share."""
    vals = [float(v) for v in values]
    above_n = sum(v > threshold for v in vals) if threshold is not None else 0
    return TailStats(n=len(vals), median=percentile(vals, 50.0), p90=percentile(vals, 90.0),
                     max=max(vals) if vals else math.nan,
                     threshold=math.nan if threshold is None else float(threshold),
                     above=above_n / len(vals) if vals and threshold is not None else math.nan, above_n=above_n)


@dataclass(frozen=True)
class Table1Row:
    """One row of Table 1: a victim, a perturbation type and a distance measure, with its three cases.

    ``paper_measure`` says whether ``distance_name`` is the measure comparable with the paper's Table 1. ``tail``:
    the distance over every successful attack (the average case's), the share above :data:`PAPER_WORST` for the
    paper's measure only.
    """

    victim: str
    perturbation: str
    distance_name: str
    instances: int
    incomplete: int
    targets: int
    best: CaseStats
    average: CaseStats
    worst: CaseStats
    paper_measure: bool = False
    tail: Optional[TailStats] = None


@dataclass(frozen=True)
class Table2Row:
    """One row of Table 2: multi-view attacks of one setting."""

    victim: str
    perturbation: str
    num_views: int
    azimuth_range: Tuple[float, float]
    attacks: int
    attack_view_success: float
    unseen_success: float
    pair: str = ""  #: ``"chair -> sofa"`` in a per-class table (:func:`table2` with ``per_class``); empty when pooled
    benign_correct: int = 0  #: attacks whose victim classified every benign attack view as the source class
    #: attacks whose benign render was the source class on every attack view and every unseen view (``None``: no
    #: record of the row says, i.e. jobs recorded before the unseen views were judged benignly)
    benign_all_views: Optional[int] = None


def _mean(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else math.nan


def victim_label(spec: Dict[str, Any]) -> str:
    """The victim column of a job: its victim, with ``[protocol]`` for jobs of an extra attack protocol (``[retry 2]``
    for a second-stage retry: :func:`meshadv.experiments.retries.protocol_label`)."""
    protocol = protocol_label(spec)
    return spec["victim"] + (f" [{protocol}]" if protocol else "")


def labelled_by_protocol(rows: Sequence[Dict[str, Any]], specs: Dict[str, Dict[str, Any]]) -> List[Dict[str, Any]]:
    """Transfer ``rows`` (keyed by ``case_id``) with ``victim`` named as :func:`victim_label` names it when the case is
    a job (``specs``: job id -> spec), so that Table 3 keeps an extra protocol's attacks apart as Table 1 does; other
    rows unchanged."""
    return [dict(row, victim=victim_label(specs[row["case_id"]])) if row.get("case_id") in specs else row
            for row in rows]


def instance_key(spec: Dict[str, Any]) -> Tuple[Any, ...]:
    """The benign input a job attacks: ``(mesh path or name, rendering configuration, seed)`` (with the victim and
    perturbation type, an *instance* of the module docstring)."""
    mesh = spec["mesh"]
    return mesh.get("path") or mesh.get("name"), spec.get("config_index"), spec.get("seed")


def single_view_results(jobs: Iterable[Any]) -> Iterator[Tuple[Dict[str, Any], Dict[str, Any]]]:
    """``(spec, record)`` of every finished single-view attack among ``jobs`` (``JobRow`` objects or ``{"spec",
    "record"}`` dicts): jobs without a record, multi-view jobs and jobs whose record says ``skipped`` are left out."""
    for job in jobs:
        spec = job["spec"] if isinstance(job, dict) else job.spec
        record = job["record"] if isinstance(job, dict) else job.record
        if record is not None and spec.get("kind", "single") == "single" and not record.get("skipped"):
            yield spec, record


def attack_rows(jobs: Iterable[Any], *, benign_correct_only: bool = False) -> List[AttackRow]:
    """Flatten finished single-view jobs (``JobRow`` objects or ``{"spec", "record"}`` dicts) into :class:`AttackRow`.

    Each job gives one row per measure of :data:`DISTANCE_NAMES` for its perturbation type (records written before
    the two Laplacian conventions are read by :func:`meshadv.attacks.distances.read_distance`). Jobs that
    are not done, multi-view jobs, and jobs whose record says ``skipped`` (e.g. the benign render was not classified
    as its class) are left out; with ``benign_correct_only`` also those whose record says
    ``benign_correct: false`` (the paper's protocol when the sweep attacked every configuration).
    """
    out = []
    for spec, record in single_view_results(jobs):
        if benign_correct_only and record.get("benign_correct") is False:
            continue
        perturbation = spec["perturbation"]
        key = instance_key(spec)
        distances = record.get("distances") or {}
        victim = victim_label(spec)
        for measure in DISTANCE_NAMES.get(perturbation, ("distance",)):
            dist = read_distance(distances, measure) if distances else record.get("distance")
            if dist is None and measure not in _ALWAYS_READ:
                continue  # a record from before the perceptibility measures
            out.append(AttackRow(victim=victim, perturbation=perturbation, instance=key,
                                 source=spec["source_class"], target=spec["target"],
                                 success=bool(record.get("success")), distance=dist, measure=measure))
    return out


def table1(rows: Iterable[AttackRow]) -> List[Table1Row]:
    """Compute Table 1 (see the module docstring for the exact definitions).

    Args:
        rows: finished attacks.

    Returns:
        One row per (victim, perturbation), sorted.
    """
    groups: Dict[Tuple[str, str, str], Dict[Any, List[AttackRow]]] = defaultdict(lambda: defaultdict(list))
    for row in rows:
        groups[(row.victim, row.perturbation, row.measure)][row.instance].append(row)
    out = []
    for (victim, perturbation, measure), instances in sorted(groups.items()):
        n_targets = max(len(v) for v in instances.values())
        best_s, best_d, worst_s, worst_d, avg_s, avg_d = [], [], [], [], [], []
        incomplete = 0
        for attacks in instances.values():
            avg_s.append(_mean([float(a.success) for a in attacks]))
            avg_d.extend(a.distance for a in attacks if a.success and a.distance is not None)
            if len(attacks) < n_targets:
                incomplete += 1
                continue
            won = [a for a in attacks if a.success]
            best_s.append(1.0 if won else 0.0)
            dists = [a.distance for a in won if a.distance is not None]
            if dists:
                best_d.append(min(dists))
            all_won = len(won) == len(attacks)
            worst_s.append(1.0 if all_won else 0.0)
            if all_won and dists:
                worst_d.append(max(dists))
        paper_measure = PAPER_COMPARABLE.get(perturbation) == measure
        out.append(Table1Row(
            victim=victim, perturbation=perturbation, distance_name=measure,
            instances=len(instances), incomplete=incomplete, targets=n_targets,
            best=CaseStats(_mean(best_s), _mean(best_d), len(best_s)),
            average=CaseStats(_mean(avg_s), _mean(avg_d), len(avg_s)),
            worst=CaseStats(_mean(worst_s), _mean(worst_d), len(worst_s)),
            paper_measure=paper_measure,
            tail=tail_stats(avg_d, PAPER_WORST.get(perturbation) if paper_measure else None),
        ))
    return out


@dataclass(frozen=True)
class PairSuccess:
    """Table 1's attacks of one (victim, perturbation type, source class, target class): ``successes`` of
    ``attacks``."""

    victim: str
    perturbation: str
    source: str
    target: str
    attacks: int
    successes: int


def pair_success(rows: Iterable[AttackRow]) -> List[PairSuccess]:
    """Count the attacks of ``rows`` (as from :func:`attack_rows`) and their successes per (victim, type, source,
    target), sorted. Each job counts once: only its rows in the first measure of :data:`DISTANCE_NAMES`."""
    counts: Dict[Tuple[str, str, str, str], List[int]] = defaultdict(lambda: [0, 0])
    for row in rows:
        if row.measure != DISTANCE_NAMES.get(row.perturbation, ("distance",))[0]:
            continue
        cell = counts[(row.victim, row.perturbation, row.source, row.target)]
        cell[0] += 1
        cell[1] += int(row.success)
    return [PairSuccess(*key, attacks=n, successes=won) for key, (n, won) in sorted(counts.items())]


def _ratio_cell(won: int, n: int) -> str:
    """``"won/n"``, bold when some attack failed."""
    return f"**{won}/{n}**" if won < n else f"{won}/{n}"


def pair_success_markdown(pairs: Sequence[PairSuccess]) -> str:
    """One Markdown matrix per (victim, type) of :func:`pair_success`'s counts: rows the source class, columns the
    target, cells ``successes/attacks`` (bold when some attack failed), and a last row with each target's total."""
    if not pairs:
        return "_no results_\n"
    groups: Dict[Tuple[str, str], List[PairSuccess]] = defaultdict(list)
    for pair in pairs:
        groups[(pair.victim, pair.perturbation)].append(pair)
    blocks = []
    for (victim, perturbation), cells in sorted(groups.items()):
        sources = sorted({c.source for c in cells})
        targets = sorted({c.target for c in cells})
        by_key = {(c.source, c.target): c for c in cells}
        lines = [f"**{victim}, {perturbation}**: successful / attacks (source class in rows, target in columns)", "",
                 "| source \\ target | " + " | ".join(targets) + " | all targets |",
                 "|---|" + "---|" * (len(targets) + 1)]
        for source in sources:
            row = [by_key.get((source, t)) for t in targets]
            n, won = sum(c.attacks for c in row if c), sum(c.successes for c in row if c)
            lines.append(f"| {source} | " + " | ".join(_ratio_cell(c.successes, c.attacks) if c else "–" for c in row)
                         + f" | {_ratio_cell(won, n)} |")
        totals = [[c for c in cells if c.target == t] for t in targets]
        n, won = sum(c.attacks for c in cells), sum(c.successes for c in cells)
        lines.append("| all sources | " + " | ".join(
            _ratio_cell(sum(c.successes for c in col), sum(c.attacks for c in col)) for col in totals)
            + f" | {_ratio_cell(won, n)} |")
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


def table2(jobs: Iterable[Any], *, per_class: bool = False) -> List[Table2Row]:
    """Compute Table 2 from finished multi-view jobs (``JobRow`` objects or ``{"spec", "record"}`` dicts).

    A job's unseen success rate is the fraction of its unseen views on which the target is reached
    (``record["eval_success_rate"]``).

    Args:
        jobs: finished jobs; single-view, skipped and unfinished ones are left out.
        per_class: one row per (source class, target) and cell instead of pooling the classes of a cell (the
            paper's Table 2 pools them); the rows' ``pair`` names the class and its target.
    """
    groups: Dict[Tuple[Any, ...], List[Tuple[bool, float, bool, Optional[bool]]]] = defaultdict(list)
    for job in jobs:
        spec = job["spec"] if isinstance(job, dict) else job.spec
        record = job["record"] if isinstance(job, dict) else job.record
        if record is None or spec.get("kind") != "multiview" or record.get("skipped"):
            continue
        rate = record.get("eval_success_rate")
        if rate is None:
            continue
        pair = f"{spec['source_class']} -> {spec['target']}" if per_class else ""
        key = (spec["victim"], spec["perturbation"], int(spec["num_views"]), tuple(spec["azimuth_range"]), pair)
        attack_views_right = bool(record.get("benign_correct"))
        unseen_right = record.get("benign_unseen_correct")
        all_right = None if unseen_right is None else attack_views_right and bool(unseen_right)
        groups[key].append((bool(record.get("success")), float(rate), attack_views_right, all_right))
    return [
        Table2Row(victim=k[0], perturbation=k[1], num_views=k[2], azimuth_range=(float(k[3][0]), float(k[3][1])),
                  attacks=len(v), attack_view_success=_mean([float(s) for s, _, _, _ in v]),
                  unseen_success=_mean([r for _, r, _, _ in v]), pair=k[4],
                  benign_correct=sum(c for _, _, c, _ in v),
                  benign_all_views=(None if all(a is None for *_, a in v) else sum(bool(a) for *_, a in v)))
        for k, v in sorted(groups.items())
    ]


def format_cell(value: Optional[float], kind: str = "num") -> str:
    """A Markdown cell: ``kind`` ``"pct"`` a fraction as a percentage (one decimal), else 3 significant digits;
    ``–`` for a missing or NaN value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if kind == "pct":
        return f"{100.0 * value:.1f}%"
    return f"{value:.3g}"


def above_text(tail: Optional[TailStats]) -> str:
    """``"4.9% (2 of 41 > 0.0003)"``: the share of successes above the tail's threshold; ``"–"`` without one."""
    if tail is None or math.isnan(tail.threshold) or tail.n == 0:
        return "–"
    return f"{100.0 * tail.above:.1f}% ({tail.above_n} of {tail.n} > {tail.threshold:.2g})"


def tail_cells(tail: Optional[TailStats]) -> str:
    """The four Markdown cells of a :class:`TailStats` (median, p90, max, share above the threshold)."""
    if tail is None:
        return " | ".join(["–"] * 4)
    return (f"{format_cell(tail.median, 'num')} | {format_cell(tail.p90, 'num')} | {format_cell(tail.max, 'num')} | "
            f"{above_text(tail)}")


def _flat(row: Any) -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for key, value in asdict(row).items():
        if key == "tail" and value is None:  # rows without tail statistics keep the same columns
            value = {f.name: None for f in fields(TailStats)}
        if isinstance(value, dict):
            for sub, v in value.items():
                out[f"{key}_{sub}"] = v
        elif isinstance(value, tuple):
            out[key] = "-".join(f"{v:g}" for v in value)
        else:
            out[key] = value
    return out


def to_csv(rows: Sequence[Any]) -> str:
    """CSV text of Table 1 or Table 2 rows (nested cases flattened to ``best_success_rate``, ``tail_p90`` etc.)."""
    buf = io.StringIO()
    flat = [_flat(r) for r in rows]
    if not flat:
        return ""
    writer = csv.DictWriter(buf, fieldnames=list(flat[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(flat)
    return buf.getvalue()


def to_markdown(rows: Sequence[Any]) -> str:
    """Markdown table of Table 1 or Table 2 rows, laid out as in the paper."""
    if not rows:
        return "_no results_\n"
    if isinstance(rows[0], Table1Row):
        lines = ["| victim | type | distance | paper's measure | best: dist | best: success | average: dist | "
                 "average: success | worst: dist | worst: success | instances | targets | successes: median dist | "
                 "successes: p90 dist | successes: max dist | successes above the paper's worst |",
                 "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(
                f"| {r.victim} | {r.perturbation} | {r.distance_name} | {'yes' if r.paper_measure else 'no'} | "
                f"{format_cell(r.best.distance, 'num')} | "
                f"{format_cell(r.best.success_rate, 'pct')} | {format_cell(r.average.distance, 'num')} | "
                f"{format_cell(r.average.success_rate, 'pct')} | {format_cell(r.worst.distance, 'num')} | "
                f"{format_cell(r.worst.success_rate, 'pct')} | {r.instances}"
                + (f" ({r.incomplete} incomplete)" if r.incomplete else "") + f" | {r.targets} | "
                + tail_cells(r.tail) + " |")
        return "\n".join(lines) + "\n"
    per_class = any(r.pair for r in rows)
    lines = ["| victim | type | " + ("class -> target | " if per_class else "") + "attack views | azimuth range | "
             "attacks | benign attack views all right | benign attack and unseen views all right | "
             "success on attack views | success on unseen views |",
             "|---|---|---|---|---|---|---|---|---|" + ("---|" if per_class else "")]
    for r in rows:
        all_views = "–" if r.benign_all_views is None else str(r.benign_all_views)
        lines.append(f"| {r.victim} | {r.perturbation} | " + (f"{r.pair} | " if per_class else "")
                     + f"{r.num_views} | {r.azimuth_range[0]:g}°–{r.azimuth_range[1]:g}° | {r.attacks} | "
                     f"{r.benign_correct} | {all_views} | {format_cell(r.attack_view_success, 'pct')} | "
                     f"{format_cell(r.unseen_success, 'pct')} |")
    return "\n".join(lines) + "\n"
