"""An extra attack protocol beside the sweep's main attack, attack by attack (e.g. the paper's Adam + lambda search
beside ``method="ddn"``).

A sweep can run an extra protocol (a job spec with ``protocol``, e.g. ``"paper"``) on a subset of the instances
its main attack also attacks. Table 1 pools each protocol's attacks over its own instances, which compares
populations of different sizes; here each extra-protocol attack is paired with the main attack of the same victim,
perturbation type, instance (mesh, rendering configuration, seed) and target, so that the two are compared on the
same inputs: success, the paper's distance (:data:`meshadv.attacks.distances.PAPER_COMPARABLE`), for shape attacks
the largest vertex displacement (which the Laplacian does not see: a smooth flow, e.g. a bend of the whole mesh, has
a small Laplacian however far it moves the vertices), the step of the first success and the CPU time.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from statistics import median
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

from meshadv.attacks.distances import PAPER_COMPARABLE, read_distance
from meshadv.experiments.retries import protocol_label
from meshadv.experiments.tables import format_cell, instance_key, single_view_results, to_csv
from meshadv.util.atomic import write_text_atomic

__all__ = ["AttackOutcome", "ProtocolPair", "ProtocolSummary", "protocol_pairs", "protocol_summary",
           "protocol_summary_markdown", "protocol_pairs_markdown", "protocol_section",
           "SECTION_INTRO"]


@dataclass(frozen=True)
class AttackOutcome:
    """What one attack job achieved.

    Attributes:
        success: the target was reached. distance: the paper's measure of its result (``None``: not recorded).
        max_displacement: the largest vertex displacement / bounding-box diagonal (shape; ``None`` otherwise).
        steps_to_success: the first step at which the target held (``None``: never). cpu_s: the job's CPU seconds
            (its wall time for records without them). method: the update rule (``attack_config["method"]``, ``None``
            in records without it).
    """

    success: bool
    distance: Optional[float]
    max_displacement: Optional[float]
    steps_to_success: Optional[int]
    cpu_s: Optional[float]
    method: Optional[str] = None


@dataclass(frozen=True)
class ProtocolPair:
    """One target of one instance attacked by the main attack and by an extra protocol.

    Attributes:
        victim, perturbation, protocol: the group. instance: ``"mesh#configuration"``. source, target: classes.
        main, extra: the main attack's and the extra protocol's :class:`AttackOutcome`.
    """

    victim: str
    perturbation: str
    protocol: str
    instance: str
    source: str
    target: str
    main: AttackOutcome
    extra: AttackOutcome


@dataclass(frozen=True)
class ProtocolSummary:
    """The :class:`ProtocolPair` of one (victim, perturbation, protocol) summed up.

    Attributes:
        pairs: paired attacks. instances: distinct instances among them. main_successes, extra_successes: targets
            reached by each. both: reached by both. extra_lower: of ``both``, those where the extra protocol's
            distance is lower. main_distance, extra_distance: median distance over ``both``; distance_ratio: median
            of extra / main over ``both``. main_displacement, extra_displacement: median largest vertex displacement
            over ``both`` (shape; ``nan`` otherwise). main_cpu_s, extra_cpu_s: median CPU seconds per attack.
        main_method, extra_method: their update rules (``", "``-joined when they differ within the group).
    """

    victim: str
    perturbation: str
    protocol: str
    pairs: int
    instances: int
    main_successes: int
    extra_successes: int
    both: int
    extra_lower: int
    main_distance: float
    extra_distance: float
    distance_ratio: float
    main_displacement: float
    extra_displacement: float
    main_cpu_s: float
    extra_cpu_s: float
    main_method: str
    extra_method: str


def _outcome(spec: Dict[str, Any], record: Dict[str, Any]) -> AttackOutcome:
    """The :class:`AttackOutcome` of a finished job's record."""
    distances = record.get("distances") or {}
    measure = PAPER_COMPARABLE.get(spec["perturbation"])
    distance = read_distance(distances, measure) if distances and measure else record.get("distance")
    displacement = distances.get("max_displacement") if spec["perturbation"] == "shape" else None
    cpu = record.get("cpu_time", record.get("time"))
    first = record.get("steps_to_success")
    return AttackOutcome(success=bool(record.get("success")),
                         distance=None if distance is None else float(distance),
                         max_displacement=None if displacement is None else float(displacement),
                         steps_to_success=None if first is None else int(first),
                         cpu_s=None if cpu is None else float(cpu),
                         method=(record.get("attack_config") or {}).get("method"))


def _pair_key(spec: Dict[str, Any]) -> Tuple[Any, ...]:
    """What a main attack and an extra protocol's attack share when they attack the same input towards the same
    target."""
    return spec["victim"], spec["perturbation"], instance_key(spec), spec["target"]


def protocol_pairs(jobs: Iterable[Any]) -> List[ProtocolPair]:
    """Pair every finished single-view job of an extra protocol with the main job of the same victim, perturbation,
    instance and target (``jobs``: ``JobRow`` objects or ``{"spec", "record"}`` dicts; jobs not done, skipped or
    multi-view are left out, and so is an extra-protocol job without a main counterpart). Sorted by victim, type,
    protocol, source, instance and target."""
    main: Dict[Tuple[Any, ...], AttackOutcome] = {}
    extra: List[Tuple[Dict[str, Any], AttackOutcome]] = []
    for spec, record in single_view_results(jobs):
        outcome = _outcome(spec, record)
        if spec.get("protocol"):
            extra.append((spec, outcome))
        else:
            main[_pair_key(spec)] = outcome
    pairs = []
    for spec, outcome in extra:
        counterpart = main.get(_pair_key(spec))
        if counterpart is None:
            continue
        mesh, config, _ = instance_key(spec)
        pairs.append(ProtocolPair(victim=spec["victim"], perturbation=spec["perturbation"],
                                  protocol=str(protocol_label(spec)), instance=f"{mesh}#{config}",
                                  source=spec["source_class"], target=spec["target"], main=counterpart,
                                  extra=outcome))
    return sorted(pairs, key=lambda p: (p.victim, p.perturbation, p.protocol, p.source, p.instance, p.target))


def _median(values: Sequence[Optional[float]]) -> float:
    present = [v for v in values if v is not None]
    return float(median(present)) if present else math.nan


def _methods(outcomes: Iterable[AttackOutcome]) -> str:
    """The distinct update rules of ``outcomes``, sorted and ``", "``-joined (``"?"`` for unrecorded ones)."""
    return ", ".join(sorted({o.method or "?" for o in outcomes}))


def _by_group(pairs: Iterable[ProtocolPair]) -> List[Tuple[Tuple[str, str, str], List[ProtocolPair]]]:
    """``pairs`` grouped by (victim, perturbation, protocol), sorted."""
    groups: Dict[Tuple[str, str, str], List[ProtocolPair]] = defaultdict(list)
    for pair in pairs:
        groups[(pair.victim, pair.perturbation, pair.protocol)].append(pair)
    return sorted(groups.items())


def protocol_summary(pairs: Iterable[ProtocolPair]) -> List[ProtocolSummary]:
    """One :class:`ProtocolSummary` per (victim, perturbation, protocol) of ``pairs``, sorted."""
    out = []
    for (victim, perturbation, protocol), group in _by_group(pairs):
        both = [p for p in group if p.main.success and p.extra.success
                and p.main.distance is not None and p.extra.distance is not None]
        ratios = [p.extra.distance / p.main.distance for p in both if p.main.distance > 0]
        out.append(ProtocolSummary(
            victim=victim, perturbation=perturbation, protocol=protocol, pairs=len(group),
            instances=len({p.instance for p in group}),
            main_successes=sum(p.main.success for p in group), extra_successes=sum(p.extra.success for p in group),
            both=len(both), extra_lower=sum(p.extra.distance < p.main.distance for p in both),
            main_distance=_median([p.main.distance for p in both]),
            extra_distance=_median([p.extra.distance for p in both]), distance_ratio=_median(ratios),
            main_displacement=_median([p.main.max_displacement for p in both]),
            extra_displacement=_median([p.extra.max_displacement for p in both]),
            main_cpu_s=_median([p.main.cpu_s for p in group]), extra_cpu_s=_median([p.extra.cpu_s for p in group]),
            main_method=_methods(p.main for p in group), extra_method=_methods(p.extra for p in group)))
    return out


def _pct(value: Optional[float]) -> str:
    """A fraction as a percentage cell (``–`` for missing)."""
    return "–" if value is None or math.isnan(value) else f"{100.0 * value:.2g}%"


def _cells(outcome: AttackOutcome, shape: bool) -> List[str]:
    """One attack's cells: reached, distance, (largest displacement), first success, CPU s."""
    cells = ["yes" if outcome.success else "**no**", format_cell(outcome.distance)]
    if shape:
        cells.append(_pct(outcome.max_displacement))
    return cells + ["–" if outcome.steps_to_success is None else str(outcome.steps_to_success),
                    format_cell(outcome.cpu_s)]


def protocol_summary_markdown(summaries: Sequence[ProtocolSummary]) -> str:
    """The Markdown table of ``summaries``, one row per (victim, type, protocol)."""
    columns = ["victim", "type", "protocol", "update rules: main, protocol", "paired attacks (instances)",
               "reached: main", "reached: protocol", "reached by both", "protocol's distance lower",
               "median distance: main", "median distance: protocol", "median ratio protocol / main",
               "median largest displacement: main", "median largest displacement: protocol", "median CPU s: main",
               "median CPU s: protocol"]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for s in summaries:
        lines.append(f"| {s.victim} | {s.perturbation} | {s.protocol} | {s.main_method}, {s.extra_method} | "
                     f"{s.pairs} ({s.instances}) | "
                     f"{s.main_successes}/{s.pairs} | {s.extra_successes}/{s.pairs} | {s.both} | "
                     f"{s.extra_lower}/{s.both} | {format_cell(s.main_distance)} | {format_cell(s.extra_distance)} | "
                     f"{format_cell(s.distance_ratio)} | {_pct(s.main_displacement)} | {_pct(s.extra_displacement)} | "
                     f"{format_cell(s.main_cpu_s)} | {format_cell(s.extra_cpu_s)} |")
    return "\n".join(lines) + "\n"


def protocol_pairs_markdown(pairs: Sequence[ProtocolPair]) -> str:
    """One Markdown table per (victim, type, protocol) of ``pairs``: the two attacks of a pair side by side."""
    blocks = []
    for (victim, perturbation, protocol), group in _by_group(pairs):
        shape = perturbation == "shape"
        measure = PAPER_COMPARABLE.get(perturbation, "distance")
        side = ["reached", measure] + (["largest displacement"] if shape else []) + ["first success", "CPU s"]
        header = ["instance", "target"] + [f"main: {c}" for c in side] + [f"{protocol}: {c}" for c in side]
        lines = [f"**{victim}, {perturbation}: the main attack and protocol {protocol!r}, attack by attack**", "",
                 "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join([p.instance, p.target] + _cells(p.main, shape) + _cells(p.extra, shape)) + " |"
                  for p in group]
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


#: The report section's opening: what is paired and what the columns mean.
SECTION_INTRO = (
    "## An extra protocol beside the main attack, on the same attacks\n\n"
    "Each attack of an extra protocol paired with the main attack of the same victim, type, instance and target "
    "(Table 1 pools each over its own instances). Distances in the paper's measure ({measures}); medians over the "
    "attacks both reached. The largest vertex displacement is a fraction of the bounding-box diagonal: the Laplacian "
    "does not see a smooth flow however far it moves the vertices. CPU s: each job's process CPU time.\n\n")


def protocol_section(done: Sequence[Any], out_dir: Path) -> Tuple[str, List[Path]]:
    """The report section (a ``meshadv.experiments.report.ReportSection``): ``protocols.md`` (the summary and every
    paired attack), ``protocols.csv`` (one row per paired attack) and the README text (the summary), or
    ``("", [])`` when no extra protocol has a paired attack."""
    pairs = protocol_pairs(done)
    if not pairs:
        return "", []
    intro = SECTION_INTRO.format(measures=", ".join(f"{k}: {v}" for k, v in PAPER_COMPARABLE.items()))
    summary = protocol_summary_markdown(protocol_summary(pairs))
    files = [write_text_atomic(out_dir / "protocols.md", intro + summary + "\n" + protocol_pairs_markdown(pairs)),
             write_text_atomic(out_dir / "protocols.csv", to_csv(pairs))]
    link = "\nEvery paired attack: [protocols.md](protocols.md), [protocols.csv](protocols.csv).\n"
    return intro + summary + link, files
