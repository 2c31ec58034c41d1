"""Analyse a perceptual study's answers: the share of answers choosing the true class, as in the MeshAdv paper.

The unit is the participant's session (one run of the page, ``session`` in the answers): for each session the share of
its adversarial trials answered with the true class, then mean ± sample standard deviation over sessions — the
paper's "99.29 ± 1.96%" (3,820 answers, 49 participants). The same is given per perturbation type, victim, target
class and distortion bin (tertiles of the attack distance within each perturbation type), and for the benign controls.
Sessions that fail an attention check are dropped first (and counted); answers read twice (the CSV and the JSON of one
session) are counted once.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from meshadv.experiments.paper import HUMAN_STUDY

__all__ = ["PAPER", "GroupStat", "StudySummary", "load_answers", "analyze", "write_analysis"]

#: The paper's user study (from :data:`meshadv.experiments.paper.HUMAN_STUDY`): share choosing the true class in
#: percent (mean and std over participants), answers, participants.
PAPER = {"mean_pct": 100 * HUMAN_STUDY["true_class_rate"], "std_pct": 100 * HUMAN_STUDY["std"],
         "answers": HUMAN_STUDY["answers"], "participants": HUMAN_STUDY["participants"]}

_BOOL = {"true": True, "false": False, "1": True, "0": False}
_FLOATS = ("distance", "fixation_ms", "exposure_ms", "exposure_target_ms", "frame_ms", "onset_ms", "rt_ms")


@dataclass(frozen=True)
class GroupStat:
    """The true-class share of one group of trials.

    Attributes:
        group: e.g. ``"all"``, ``"perturbation: shape"``, ``"victim: v1"``.
        answers: number of answers. participants: sessions with at least one answer in the group.
        mean: mean over sessions of the share choosing the true class (0-1). std: sample std over sessions (0 with
            one session).
    """

    group: str
    answers: int
    participants: int
    mean: float
    std: float


@dataclass
class StudySummary:
    """Everything :func:`analyze` measured.

    Attributes:
        adversarial: per-group stats over adversarial trials (first row: all of them).
        controls: stats over benign controls (``None`` without controls).
        sessions: sessions read. dropped_attention: sessions dropped for failing an attention check.
        answers_read: answer rows read (after removing duplicates).
        exposure: exposure timing over all kept trials (``mean_ms``, ``std_ms``, ``min_ms``, ``max_ms``,
            ``target_ms``, and ``off_target_trials``: trials shown more than ``tolerance_ms`` away from the target,
            e.g. because the participant switched tabs and the browser stopped drawing).
    """

    adversarial: List[GroupStat] = field(default_factory=list)
    controls: Optional[GroupStat] = None
    sessions: int = 0
    dropped_attention: int = 0
    answers_read: int = 0
    exposure: Dict[str, float] = field(default_factory=dict)

    def to_record(self) -> Dict[str, Any]:
        """JSON-able form."""
        return {"adversarial": [asdict(g) for g in self.adversarial],
                "controls": None if self.controls is None else asdict(self.controls), "sessions": self.sessions,
                "dropped_attention": self.dropped_attention, "answers_read": self.answers_read,
                "exposure": self.exposure, "paper": PAPER}


def _normalise(row: Dict[str, Any], origin: str) -> Dict[str, Any]:
    out = dict(row)
    for key in ("correct", "true_first"):
        value = out.get(key)
        if isinstance(value, str):
            if value.lower() not in _BOOL:
                raise ValueError(f"answers {origin}: column {key!r} must be true/false, got {value!r}")
            out[key] = _BOOL[value.lower()]
    for key in _FLOATS:
        value = out.get(key)
        out[key] = None if value in (None, "") else float(value)
    for key in ("participant", "trial"):
        if out.get(key) not in (None, ""):
            out[key] = int(out[key])
    missing = [k for k in ("kind", "correct", "image_id") if out.get(k) in (None, "")]
    if missing:
        raise ValueError(f"answers {origin}: a row lacks {missing}; is this a meshadv study answers file?")
    out.setdefault("session", f"{out.get('study_id')}/p{out.get('participant')}")
    return out


def load_answers(paths: Sequence[Union[str, Path]]) -> List[Dict[str, Any]]:
    """Read answer files downloaded from the study page (CSV or JSON, any mix), removing duplicates.

    Args:
        paths: the files.

    Returns:
        One dict per answer, typed (booleans, floats, ints).

    Raises:
        FileNotFoundError: a file is missing. ValueError: a file is not a study answers file.
    """
    rows: List[Dict[str, Any]] = []
    for path in map(Path, paths):
        if not path.is_file():
            raise FileNotFoundError(f"answers file {path} does not exist")
        text = path.read_text(encoding="utf-8")
        if path.suffix.lower() == ".json":
            data = json.loads(text)
            items = data.get("answers") if isinstance(data, dict) else data
            if not isinstance(items, list):
                raise ValueError(f"answers file {path}: expected a list of answers or an object with 'answers'")
        else:
            items = list(csv.DictReader(io.StringIO(text)))
        rows += [_normalise(r, str(path)) for r in items]
    seen = set()
    unique = []
    for r in rows:
        key = (r.get("study_id"), r["session"], r.get("trial"), r["image_id"])
        if key not in seen:
            seen.add(key)
            unique.append(r)
    return unique


def _stat(group: str, rows: List[Dict[str, Any]]) -> GroupStat:
    by_session: Dict[str, List[bool]] = defaultdict(list)
    for r in rows:
        by_session[r["session"]].append(bool(r["correct"]))
    shares = [sum(v) / len(v) for v in by_session.values()]
    n = len(shares)
    mean = sum(shares) / n if n else float("nan")
    std = math.sqrt(sum((s - mean) ** 2 for s in shares) / (n - 1)) if n > 1 else 0.0
    return GroupStat(group, len(rows), n, mean, std)


def _distance_bins(rows: List[Dict[str, Any]], bins: int = 3) -> Dict[int, str]:
    """Label each row (by index) with its distance tertile within its perturbation type."""
    labels: Dict[int, str] = {}
    by_type: Dict[str, List[int]] = defaultdict(list)
    for i, r in enumerate(rows):
        if r.get("distance") is not None:
            by_type[r.get("perturbation") or "?"].append(i)
    for perturbation, idx in by_type.items():
        values = sorted({rows[i]["distance"] for i in idx})
        k = min(bins, len(values))
        edges = [values[min(len(values) - 1, (j * len(values)) // k)] for j in range(k)] + [values[-1]]
        for i in idx:
            d = rows[i]["distance"]
            j = max(b for b in range(k) if d >= edges[b])
            labels[i] = f"distance: {perturbation} bin {j + 1}/{k} [{edges[j]:.3g}, {edges[j + 1]:.3g}]"
    return labels


def analyze(rows: List[Dict[str, Any]], *, drop_failed_attention: bool = True,
            exposure_tolerance_ms: float = 50.0) -> StudySummary:
    """The paper's statistics over answers from :func:`load_answers`.

    Args:
        rows: the answers.
        drop_failed_attention: drop every session that answered an attention check wrong.
        exposure_tolerance_ms: a trial whose measured exposure is further than this from its target is counted in
            ``exposure["off_target_trials"]``.

    Returns:
        A :class:`StudySummary`.

    Raises:
        ValueError: no adversarial answer is left.
    """
    out = StudySummary(answers_read=len(rows))
    sessions = {r["session"] for r in rows}
    out.sessions = len(sessions)
    failed = {r["session"] for r in rows if r["kind"] == "attention" and not r["correct"]}
    if drop_failed_attention:
        out.dropped_attention = len(failed)
        rows = [r for r in rows if r["session"] not in failed]
    adv = [r for r in rows if r["kind"] == "adversarial"]
    if not adv:
        raise ValueError("no adversarial answers left to analyse (after attention-check filtering)")
    out.adversarial.append(_stat("all", adv))
    groups: Dict[str, List[Dict[str, Any]]] = defaultdict(list)
    for r in adv:
        for key in ("perturbation", "victim", "target"):
            groups[f"{'target class' if key == 'target' else key}: {r.get(key) or '?'}"].append(r)
    for i, label in sorted(_distance_bins(adv).items()):
        groups[label].append(adv[i])
    order = ("perturbation", "victim", "target class", "distance")
    names = sorted(groups, key=lambda n: (order.index(n.split(":")[0]), n))
    out.adversarial += [_stat(name, groups[name]) for name in names]
    controls = [r for r in rows if r["kind"] == "control"]
    out.controls = _stat("benign controls", controls) if controls else None
    timed = [r for r in rows if r.get("exposure_ms") is not None]
    if timed:
        times = [r["exposure_ms"] for r in timed]
        mean = sum(times) / len(times)
        off = sum(abs(r["exposure_ms"] - (r.get("exposure_target_ms") or 0.0)) > exposure_tolerance_ms for r in timed)
        out.exposure = {"mean_ms": mean, "std_ms": math.sqrt(sum((t - mean) ** 2 for t in times) / len(times)),
                        "min_ms": min(times), "max_ms": max(times),
                        "target_ms": float(timed[0].get("exposure_target_ms") or 0.0), "off_target_trials": off,
                        "tolerance_ms": float(exposure_tolerance_ms)}
    return out


def _pct(g: GroupStat) -> str:
    return f"{100 * g.mean:.2f} ± {100 * g.std:.2f}%"


def _markdown(summary: StudySummary) -> str:
    all_ = summary.adversarial[0]
    lines = ["# Perceptual study: share of answers choosing the true class", "",
             "Mean ± sample standard deviation over participants (one session of the page each) of the share of "
             "their answers naming the object's true class rather than the attack's target, after a 2 s exposure.",
             "",
             f"Sessions read: {summary.sessions}; dropped for failing an attention check: "
             f"{summary.dropped_attention}; answers read: {summary.answers_read}.", "",
             "| | answers | participants | true class chosen |", "|---|---|---|---|",
             f"| MeshAdv paper (Xiao et al. 2019) | {PAPER['answers']} | {PAPER['participants']} | "
             f"{PAPER['mean_pct']:.2f} ± {PAPER['std_pct']:.2f}% |",
             f"| **this study, adversarial images** | {all_.answers} | {all_.participants} | {_pct(all_)} |"]
    if summary.controls is not None:
        c = summary.controls
        lines.append(f"| this study, benign controls | {c.answers} | {c.participants} | {_pct(c)} |")
    lines += ["", "## By perturbation type, victim, target class and distortion bin", "",
              "| group | answers | participants | true class chosen |", "|---|---|---|---|"]
    lines += [f"| {g.group} | {g.answers} | {g.participants} | {_pct(g)} |" for g in summary.adversarial[1:]]
    if summary.exposure:
        e = summary.exposure
        lines += ["", f"Exposure measured in the page (requestAnimationFrame frame times): mean {e['mean_ms']:.1f} ms, "
                      f"std {e['std_ms']:.1f} ms, range {e['min_ms']:.1f}-{e['max_ms']:.1f} ms "
                      f"(target {e['target_ms']:.0f} ms); {e['off_target_trials']} trials off by more than "
                      f"{e['tolerance_ms']:.0f} ms."]
    lines += ["", "Figure: [true_class_share.png](true_class_share.png). Numbers: summary.json.", ""]
    return "\n".join(lines)


def _figure(summary: StudySummary) -> bytes:
    """The bar chart (PNG bytes): the paper's bar, then ours per group, then the controls."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows: List[Tuple[str, float, float]] = [
        (f"paper ({PAPER['participants']} participants)", PAPER["mean_pct"], PAPER["std_pct"])]
    rows += [(f"{g.group} (n={g.participants})", 100 * g.mean, 100 * g.std) for g in summary.adversarial]
    if summary.controls is not None:
        rows.append((f"benign controls (n={summary.controls.participants})", 100 * summary.controls.mean,
                     100 * summary.controls.std))
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(rows) + 1.2))
    y = list(range(len(rows)))[::-1]
    colours = ["#999999"] + ["#3b6ea8"] * len(summary.adversarial) + ["#6aa84f"] * (summary.controls is not None)
    ax.barh(y, [r[1] for r in rows], xerr=[r[2] for r in rows], color=colours, capsize=3)
    ax.set_yticks(y, [r[0] for r in rows], fontsize=8)
    ax.set_xlim(0, 105)
    ax.axvline(50, color="k", lw=0.6, ls=":")
    ax.set_xlabel("answers choosing the true class (%, mean ± std over participants)")
    ax.set_title("2AFC after a 2 s exposure: true class vs. adversarial target")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    return buf.getvalue()


def write_analysis(paths: Sequence[Union[str, Path]], out_dir: Union[str, Path], *,
                   drop_failed_attention: bool = True) -> StudySummary:
    """Read answer files and write ``README.md``, ``summary.json`` and ``true_class_share.png`` into ``out_dir``.

    Args:
        paths: answer files (CSV/JSON) downloaded from the study page.
        out_dir: the output folder (created).
        drop_failed_attention: drop sessions that failed an attention check.

    Returns:
        The summary.

    Raises:
        FileNotFoundError, ValueError: as :func:`load_answers` and :func:`analyze`.
    """
    from meshadv.util.atomic import write_bytes_atomic

    summary = analyze(load_answers(paths), drop_failed_attention=drop_failed_attention)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(out / "true_class_share.png", _figure(summary))
    write_bytes_atomic(out / "summary.json", json.dumps(summary.to_record(), indent=2).encode("utf-8"))
    write_bytes_atomic(out / "README.md", _markdown(summary).encode("utf-8"))
    return summary
