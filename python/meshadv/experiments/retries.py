"""The retry pass: a main-setting attack that failed runs again with a larger budget (``[attack.retry]``), and a
retry that failed again with the next stage's options (``[[attack.retry]]``, stages in order).

An attack with a fixed budget (ddn's 300 shape / 100 texture steps) misses some targets that the same attack reaches
with more steps, because its step size anneals over the budget it is given. Running every attack with the larger
budget would multiply the sweep's cost; running it again only where the first run failed costs a few percent, as an
ensemble of attacks does (AutoAttack runs each attack only on the inputs the previous ones did not break).

A retry job is its parent's spec with the retry options over the parent's attack options, ``"protocol": "retry"``
(so the tables, Table 3 and ``meshadv sweep --only retry`` treat the retries as one more part of the sweep) and
``"retry_of": <parent job id>``. It starts from the benign mesh, not from the failed result, and its seed is the
parent's. :func:`with_retries` combines each main attack with its retry: the retry's outcome where the parent
failed, the parent's otherwise; the tables report that as the victim's ``[+retry]`` row beside the plain one.
"""

from __future__ import annotations

from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Set

__all__ = ["COMBINED_PART", "RETRY_PART", "RetryStages", "is_main_single", "is_retry", "place_retries",
           "protocol_label", "retry_jobs", "retry_options", "retry_spec", "retry_stage", "superseded_retries",
           "with_retries", "with_retried_transfers"]

#: The retry stages of a sweep (the config's ``[attack.retry]`` as a list): per stage, perturbation type -> options.
RetryStages = Sequence[Mapping[str, Mapping[str, Any]]]

#: The part (``job_part``) and protocol name of the retry jobs.
RETRY_PART = "retry"
#: The protocol name the tables give a main attack combined with its retry (:func:`with_retries`).
COMBINED_PART = "+retry"


def is_retry(spec: Mapping[str, Any]) -> bool:
    """Whether ``spec`` is a retry job."""
    return "retry_of" in spec


def is_main_single(spec: Mapping[str, Any]) -> bool:
    """True for a job of the main setting's single-view attacks: no extra protocol, no retry, not multi-view."""
    return spec.get("kind", "single") == "single" and not spec.get("protocol")


def retry_stage(spec: Mapping[str, Any]) -> int:
    """The retry stage of the job ``spec``: 0 for a job that is not a retry, 1 for a retry of a main attack, ``k``
    for a retry of a stage ``k - 1`` retry."""
    return int(spec.get("retry_stage", 1)) if is_retry(spec) else 0


def protocol_label(spec: Mapping[str, Any]) -> Optional[str]:
    """The protocol name the tables give the job ``spec``: its ``protocol`` entry (``None`` for the main setting),
    with the stage for a retry past the first (``"retry 2"``)."""
    protocol = spec.get("protocol")
    stage = retry_stage(spec)
    return f"{protocol} {stage}" if protocol and stage > 1 else protocol


def retry_options(stages: RetryStages, spec: Mapping[str, Any]) -> Optional[Mapping[str, Any]]:
    """The options a failure of the job ``spec`` is retried with: those of the next retry stage of ``stages`` (the
    config's ``[attack.retry]``: per stage, type -> options) for its perturbation type, when ``spec`` is a
    main-setting single-view job (stage 1) or a retry with a stage after its own; else ``None`` (not retried)."""
    stage = retry_stage(spec)
    if (stage == 0 and not is_main_single(spec)) or stage >= len(stages):
        return None
    return stages[stage].get(spec["perturbation"])


def retry_spec(spec: Mapping[str, Any], parent_id: str, options: Mapping[str, Any]) -> Dict[str, Any]:
    """The retry job of the job ``parent_id`` (spec ``spec``: a main-setting job or a retry): its attack options with
    ``options`` over them, ``"protocol": "retry"``, ``"retry_of": parent_id`` and, past the first stage,
    ``"retry_stage"``; everything else is the parent's."""
    child = dict(spec)
    child["attack"] = {**dict(spec.get("attack", {})), **dict(options)}
    child["protocol"] = RETRY_PART
    child["retry_of"] = parent_id
    stage = retry_stage(spec) + 1
    if stage > 1:
        child["retry_stage"] = stage
    return child


def retry_jobs(stages: RetryStages, rows: Iterable[Any]) -> List[Dict[str, Any]]:
    """The retries of ``stages`` along each finished main-setting single-view job (a ``JobRow``) whose attack failed
    and was not skipped: its stage-1 retry (:func:`retry_spec` with :func:`retry_options`), and while that retry has
    finished and failed too, the next stage's retry of it, until a stage is not finished, succeeds or is the last.
    Finished ones are included, so that the list is the retry part of the sweep; in the order of ``rows``.

    A retry in ``rows`` that this walk does not reach was made by other stages (the config's ``[attack.retry]``
    changed since): :func:`superseded_retries`.
    """
    rows = list(rows)
    by_id = {row.job_id: row for row in rows}
    out = []
    for row in rows:
        if retry_stage(row.spec) == 0:
            out.extend(_chain(stages, row, by_id))
    return out


def _chain(stages: RetryStages, row: Any, by_id: Mapping[str, Any]) -> List[Dict[str, Any]]:
    """The retries of ``stages`` along the main-setting job ``row`` (:func:`retry_jobs`)."""
    from meshadv.experiments.spec import job_id

    chain: List[Dict[str, Any]] = []
    link = row
    while link is not None and link.state == "done" and link.record is not None \
            and not link.record.get("skipped") and not link.record.get("success"):
        options = retry_options(stages, link.spec)
        if options is None:
            break
        child = retry_spec(link.spec, link.job_id, options)
        chain.append(child)
        link = by_id.get(job_id(child))
    return chain


def superseded_retries(stages: Optional[RetryStages], rows: Iterable[Any]) -> Set[str]:
    """The ids of the retries in ``rows`` that the retry stages ``stages`` do not make (:func:`retry_jobs`): those of
    stages the config had before its ``[attack.retry]`` changed, and their own retries. The tables, Table 3 and the
    Mitsuba pass leave them out, so that a parent has at most one retry per stage; the database keeps them. ``None``
    (the stages are not known, e.g. a database without its config text) supersedes none."""
    from meshadv.experiments.spec import job_id

    rows = list(rows)
    if stages is None:
        return set()
    current = {job_id(spec) for spec in retry_jobs(stages, rows)}
    return {row.job_id for row in rows if is_retry(row.spec) and row.job_id not in current}


def place_retries(jobs: Sequence[Dict[str, Any]], retries: Sequence[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """``jobs`` (a sweep's expansion, in its order) with ``retries`` right after the last main-setting job, so that
    they run before the extra protocols and Table 2."""
    last_main = max((i for i, j in enumerate(jobs) if is_main_single(j)), default=-1)
    return [*jobs[:last_main + 1], *retries, *jobs[last_main + 1:]]


def with_retries(jobs: Iterable[Any]) -> List[Dict[str, Any]]:
    """Each finished main-setting single-view attack combined with its finished retries, as ``{"spec", "record"}``
    dicts for :func:`meshadv.experiments.tables.attack_rows`: the record of the first success along the chain of the
    attack and its retries (stage by stage), else of the last of them that finished; the spec is the parent's with
    ``"protocol": "+retry"``. Only the (victim, type) groups with at least one finished retry are returned (none when
    the sweep has no retries).

    Args:
        jobs: ``JobRow`` objects (finished or not).
    """
    rows = [j for j in jobs if j.state == "done" and j.record is not None]
    retried = {j.spec["retry_of"]: j for j in rows if is_retry(j.spec)}
    groups = {(j.spec["victim"], j.spec["perturbation"]) for j in rows if is_retry(j.spec)}
    out = []
    for job in rows:
        spec = job.spec
        if not is_main_single(spec) or (spec["victim"], spec["perturbation"]) not in groups:
            continue
        link = job
        while not link.record.get("success") and link.job_id in retried:
            link = retried[link.job_id]
        out.append({"spec": dict(spec, protocol=COMBINED_PART), "record": link.record})
    return out


def with_retried_transfers(rows: Sequence[Dict[str, Any]], specs: Mapping[str, Mapping[str, Any]]
                           ) -> List[Dict[str, Any]]:
    """Table 3's rows of the combined attacks (:func:`with_retries`): the transfer rows (keyed by ``case_id``, a job
    id of ``specs``) of the main attacks and of the retries once more, with ``victim`` named ``"<victim> [+retry]"``.
    Only successful attacks are transferred, so a main attack that failed has no row and its retry's rows stand for
    it. Only victims with a transferred retry get them (none without retries)."""
    def spec_of(row: Dict[str, Any]) -> Mapping[str, Any]:
        return specs.get(row.get("case_id"), {})

    retried = {spec_of(r)["victim"] for r in rows if is_retry(spec_of(r))}
    out = []
    for row in rows:
        spec = spec_of(row)
        if spec.get("victim") in retried and (is_retry(spec) or is_main_single(spec)):
            out.append(dict(row, victim=f"{spec['victim']} [{COMBINED_PART}]"))
    return out
