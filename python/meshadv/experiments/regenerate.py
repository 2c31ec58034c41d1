"""Per-job artefacts on demand: re-run a finished job from the spec and seed stored in the results database.

The database alone holds everything the tables need; meshes and renders (figures, the Mitsuba transfer pass) are
regenerated from a job's stored spec (which carries its seed) by running the same job function again into a folder
of the caller's choice. The database is only read: the regenerated record is compared with the stored one (success,
steps, distance), so a drift between the code that ran the sweep and the code that regenerates is visible.

A spec names only what its config sets; the rest comes from the code's defaults (the update rule's options, such as
``DDN_DEFAULTS``, the victim's ``load_victim(optimize=...)``). The attack job records what it ran with
(``attack_config``, ``victim_optimize``) and :func:`pinned_spec` puts those back into the spec of the rerun, so a
changed default does not change a regeneration. Records written before the job recorded them pin nothing: ``assume``
(a :data:`Assumed` mapping, e.g. a JSON file kept next to the database) says what the sweep's code used; what is
neither pinned nor assumed runs with today's defaults and is listed in :attr:`Regenerated.notes`.

Example:
    >>> out = regenerate_job("out/paper_medium/results.db", "0f3a9c...", "out/regen")   # doctest: +SKIP
    >>> out.matches, out.out_dir                                                        # doctest: +SKIP
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

from meshadv._validate import setting_flag
from meshadv.experiments.store import ResultStore, job_out_dir
from meshadv.experiments.worker import execute

__all__ = ["Regenerated", "regenerate_job", "stored_job_ref", "pinned_spec", "load_assumed", "recorded_mesh_spec",
           "COMPARED_KEYS", "Assumed", "attack_pin_key", "compute_note"]

#: What the sweep's code used where neither its specs nor its records say: ``{"victim_optimize": bool,
#: "surface_meshes": bool, "attack": {"shape": {option: value, "method_options": {...}}, "texture": {...}}}`` (every
#: key optional; ``surface_meshes``: whether jobs take a file's texture and vertex colours as they are); an attack entry
#: applies to specs of its own ``method``, and ``"<type>/<method>"`` keys (``"shape/ddn"``, ``"texture/default"``
#: for a spec without a method) take precedence over ``"<type>"`` ones.
Assumed = Mapping[str, Any]


def attack_pin_key(perturbation: Any, method: Any) -> str:
    """The ``"<type>/<method>"`` key of an :data:`Assumed` attack entry (``"default"`` for a spec without a method)."""
    return f"{perturbation}/{method or 'default'}"

_ATTACK_JOB = "meshadv.experiments.jobs:run_attack_job"

#: Record keys compared between the stored and the regenerated record (floats to a relative 1e-3).
COMPARED_KEYS = ("success", "skipped", "steps", "distance", "steps_to_success")


def compute_note(stored: Optional[Mapping[str, Any]]) -> str:
    """Why a rerun may differ from ``stored`` although nothing in its spec changed: what the stored record ran on
    (its ``compute``, :func:`~meshadv.experiments.provenance.compute_environment`; absent from records made before
    it was recorded) beside this machine's."""
    from meshadv.experiments.provenance import compute_environment

    here = compute_environment()
    then = dict((stored or {}).get("compute") or {})

    def describe(env: Mapping[str, Any]) -> str:
        return (f"{env.get('cpu', '?')}, torch kernels {env.get('torch_cpu_capability', '?')}, "
                f"{env.get('torch_threads', '?')} thread(s)")

    recorded = describe(then) if then else "not recorded (a record older than the 'compute' entry)"
    return (f"an attack is a chaotic trajectory: it reruns bit for bit only on the instruction set torch's kernels "
            f"used for it and the same thread count (ATEN_CPU_CAPABILITY=avx2 selects AVX2 kernels on an AVX-512 "
            f"CPU; a CPU of another vendor may still differ). Stored record: {recorded}; this run: "
            f"{describe(here)}")


@dataclass(frozen=True)
class Regenerated:
    """A regenerated job.

    Attributes:
        job_id: the job. out_dir: where its artefacts now are. record: the new record.
        stored: the record in the database (``None`` when the job had not finished).
        differences: ``"key: stored -> new"`` for each of :data:`COMPARED_KEYS` that differs; empty when it matches.
        notes: what the rerun could not pin (the settings it took from today's defaults), see :func:`pinned_spec`.
    """

    job_id: str
    out_dir: Path
    record: Dict[str, Any]
    stored: Optional[Dict[str, Any]]
    differences: List[str]
    notes: Tuple[str, ...] = ()

    @property
    def matches(self) -> bool:
        """Whether the regenerated record agrees with the stored one on :data:`COMPARED_KEYS`."""
        return self.stored is not None and not self.differences


def stored_job_ref(store: ResultStore) -> str:
    """The job function the sweep ran (``[runner] job`` of the config text stored in the database, else the default)."""
    from meshadv.experiments.config import DEFAULT_JOB
    from meshadv.experiments.config import raw_from_text

    text = store.get_meta("config_text")
    if not text:
        return DEFAULT_JOB
    try:
        raw = raw_from_text(text)
    except ValueError:  # an old database's text: the default
        return DEFAULT_JOB
    return str((raw.get("runner") or {}).get("job", DEFAULT_JOB))


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, (int, float)) and not isinstance(b, bool):
        return math.isclose(a, float(b), rel_tol=1e-3, abs_tol=1e-9)
    return a == b


def _merge_attack(pinned: Mapping[str, Any], spec_attack: Mapping[str, Any], perturbation: Any) -> Dict[str, Any]:
    """``pinned`` attack options (complete, as recorded or pinned) under the spec's own (the spec wins;
    ``method_options`` merged key by key); pinned ddn options lacking an option added since get the value the rule
    ran with before it (:func:`meshadv.attacks.budget.recorded_options`)."""
    merged = {**pinned, **spec_attack}
    if "method_options" in pinned or "method_options" in spec_attack:
        recorded = dict(pinned.get("method_options") or {})
        if pinned.get("method") == "ddn" and "method_options" in pinned:
            from meshadv.attacks.budget import recorded_options

            recorded = recorded_options(str(perturbation), recorded)
        merged["method_options"] = {**recorded, **(spec_attack.get("method_options") or {})}
    return merged


def pinned_spec(spec: Mapping[str, Any], stored: Optional[Mapping[str, Any]],
                assume: Optional[Assumed] = None) -> Tuple[Dict[str, Any], List[str]]:
    """The spec to rerun a job with: ``spec`` plus what its stored record says the job ran with.

    ``attack_config`` of the record (the attack's effective hyper-parameters) goes under ``spec["attack"]`` and
    ``victim_optimize`` into the spec; for a record without them, ``assume`` (see :data:`Assumed`) supplies them
    (its attack options only to specs of the same ``method``). The record's ``mesh_surface`` (false for a record
    without it, made when jobs loaded every file per face; for an unfinished job ``assume``'s ``surface_meshes``)
    goes into ``spec["mesh"]["surface"]`` (:func:`meshadv.experiments.jobs.load_job_mesh`).
    The job id is not recomputed: the rerun is the same job.

    Args:
        spec: the stored spec. stored: the stored record (``None``: not finished). assume: the sweep's defaults.

    Returns:
        ``(spec, notes)``: notes name each setting left to today's defaults.

    Raises:
        ValueError: ``assume`` is not a mapping of the documented shape.
    """
    assume = dict(assume or {})
    unknown = set(assume) - {"victim_optimize", "surface_meshes", "attack"}
    if unknown:
        raise ValueError(f"assume has unknown keys {sorted(unknown)} (known: attack, surface_meshes, victim_optimize)")
    for key in ("victim_optimize", "surface_meshes"):
        if key in assume:
            setting_flag(f"assume[{key!r}]", assume[key])
    if not isinstance(assume.get("attack", {}), Mapping):
        raise ValueError("assume['attack'] must map a perturbation type to attack options")
    out = dict(spec)
    notes: List[str] = []
    record = dict(stored or {})
    if "victim_optimize" not in out:
        if "victim_optimize" in record:
            out["victim_optimize"] = bool(record["victim_optimize"])
        elif "victim_optimize" in assume:
            out["victim_optimize"] = assume["victim_optimize"]
        else:
            notes.append("victim_optimize: neither the spec nor the record pins it; today's load_victim default used")
    out["mesh"] = recorded_mesh_spec(out, stored, assume.get("surface_meshes"))
    attack = dict(out.get("attack") or {})
    config = record.get("attack_config")
    if isinstance(config, Mapping):
        out["attack"] = _merge_attack({k: v for k, v in config.items() if k != "perturbation"}, attack,
                                      out.get("perturbation"))
    else:
        pins = assume.get("attack") or {}
        assumed = pins.get(attack_pin_key(out.get("perturbation"), attack.get("method")))
        if assumed is None:
            assumed = pins.get(str(out.get("perturbation")))
            if isinstance(assumed, Mapping) and assumed.get("method") != attack.get("method"):
                assumed = None
        if isinstance(assumed, Mapping):
            out["attack"] = _merge_attack(assumed, attack, out.get("perturbation"))
        else:  # nothing assumed for this type, or for another update rule (e.g. the paper's protocol beside ddn)
            notes.append("attack options: the record has no attack_config; options the spec does not name "
                         "(e.g. the update rule's method_options) took today's defaults")
    return out, notes


def recorded_mesh_spec(spec: Mapping[str, Any], stored: Optional[Mapping[str, Any]],
                       assumed_surface: Optional[bool] = None) -> Any:
    """``spec["mesh"]`` with ``surface`` (:func:`meshadv.experiments.jobs.load_job_mesh`) as the job ran: the stored
    record's ``mesh_surface``, false for a record without it (made when jobs loaded every file per face), else
    (an unfinished job) ``assumed_surface`` when given; the spec's own ``surface`` wins. Not a mapping: as is."""
    mesh = spec.get("mesh")
    if not isinstance(mesh, Mapping) or "surface" in mesh:
        return mesh
    if stored is not None:
        return {**mesh, "surface": bool(stored.get("mesh_surface", False))}
    if assumed_surface is not None:
        return {**mesh, "surface": bool(assumed_surface)}
    return mesh


def load_assumed(path: Union[str, Path, None]) -> Dict[str, Any]:
    """Read an :data:`Assumed` JSON file (``{}`` for ``None``).

    Raises:
        FileNotFoundError: no such file. ValueError: not a JSON object (naming the file).
    """
    if path is None:
        return {}
    from meshadv.util.json_file import read_json

    file = Path(path)
    data = read_json(file, "assumed-defaults file")
    if not isinstance(data, dict):
        raise ValueError(f"assumed-defaults file {file} must hold a JSON object")
    data = {k: v for k, v in data.items() if not k.startswith("_")}  # "_comment" and the like
    pinned_spec({}, None, data)  # validates the keys
    return data


def regenerate_job(db_path: Union[str, Path], job: str, out_dir: Optional[Union[str, Path]] = None, *,
                   threads: int = 0, assume: Optional[Assumed] = None) -> Regenerated:
    """Run job ``job`` of the database again into ``out_dir`` and compare its record with the stored one.

    Args:
        db_path: the results database.
        job: the job id (a unique prefix is enough).
        out_dir: the artefact folder (created; default ``<database folder>/jobs/<id[:2]>/<id>``).
        threads: intra-op threads (0 = process default).
        assume: what the sweep's code used where its records do not say (:func:`pinned_spec`).

    Returns:
        A :class:`Regenerated`.

    Raises:
        FileNotFoundError: no database. KeyError: no such job, or an ambiguous prefix.
        RuntimeError: the job failed (its traceback in the message).
    """
    db = Path(db_path)
    if not db.is_file():
        raise FileNotFoundError(f"results database {db} does not exist")
    # read only: regeneration only reads, so the database (a committed one too) stays byte-identical
    with ResultStore(db, read_only=True) as store:
        ids = [r.job_id for r in store.rows() if r.job_id.startswith(job)]
        if len(ids) != 1:
            raise KeyError(f"job {job!r} matches {len(ids)} jobs of {db} (give the full 16-digit id)")
        (jid,) = ids
        row = next(r for r in store.rows() if r.job_id == jid)
        ref = stored_job_ref(store)
    out = Path(out_dir) if out_dir is not None else job_out_dir(db.parent, jid)
    stored = row.record if row.state == "done" else None
    spec, notes = pinned_spec(row.spec, stored, assume) if ref == _ATTACK_JOB else (row.spec, [])
    outcome = execute(ref, jid, spec, str(out), threads=threads)
    if not outcome.ok or outcome.record is None:
        raise RuntimeError(f"job {jid} failed while regenerating:\n{outcome.error}")
    diffs = []
    if stored is not None:
        for key in COMPARED_KEYS:
            if key in stored and not _same(stored.get(key), outcome.record.get(key)):
                diffs.append(f"{key}: {stored.get(key)!r} -> {outcome.record.get(key)!r}")
    return Regenerated(jid, out, outcome.record, stored, diffs, tuple(notes))
