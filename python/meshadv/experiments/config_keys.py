"""The keys a sweep file may use, checked at load so that a misspelt key fails before any job runs.

:func:`check_keys` refuses every key not
listed here, naming its full dotted path and suggesting the closest valid key. The keys of ``[attack.shape]`` /
``[attack.texture]`` (and of protocols) are the keyword arguments of the attack classes in the family registry,
read from their signatures, so they follow the attacks without a second list.
"""

from __future__ import annotations

import inspect
from typing import Any, Dict, Iterable, List, Mapping, Tuple

from meshadv._validate import suggest
from meshadv.render.setup import SETUP_OPTIONS

__all__ = ["SECTION_KEYS", "attack_option_keys", "check_attack_values", "check_keys"]

#: Allowed keys of each top-level section (``attack`` also takes one table per perturbation name).
SECTION_KEYS: Dict[str, frozenset] = {
    "experiment": frozenset({"name", "seeds", "output", "db"}),
    "meshes": frozenset(
        {"source", "classes", "models_per_class", "models", "builtin", "files", "target_faces", "max_faces"}
    ),
    "render": frozenset(
        {
            "image_size",
            "configurations",
            "config_seed",
            "distance",
            "azimuth",
            "elevation",
            "viewing_angle",
            "light_intensity",
            "ambient",
            "light_jitter",
            "rendering_set",
        }
    ),  # fmt: skip
    "victims": frozenset({"names", "weights", "configurations"}),
    "attack": frozenset({"perturbations", "types", "targets", "benign_correct_only", "protocols", "retry"}),
    "multiview": frozenset(
        {
            "enabled",
            "view_counts",
            "azimuth_ranges",
            "grid",
            "eval_views",
            "perturbations",
            "types",
            "classes",
            "targets",
            "victims",
            "elevation",
            "distance",
        }
    ),  # fmt: skip
    "runner": frozenset({"job", "max_attempts", "timeout", "workers", "threads_per_job", "max_jobs_per_worker"}),
}
#: Allowed keys of an ``[attack.protocols.<name>]`` table besides the perturbation tables.
PROTOCOL_KEYS = frozenset({"configurations", "victims"})
#: Attack options the job runner reads itself (not passed to the attack class): the criterion's margin and the
#: render setup's options (``antialias``, ...).
JOB_ATTACK_OPTIONS = frozenset({"required_margin", *SETUP_OPTIONS})


def attack_option_keys(attack_class: type) -> List[str]:
    """The keyword arguments accepted by ``attack_class`` and its bases (``**kwargs`` forwarded up the MRO)."""
    keys = set()
    for klass in attack_class.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        for param in inspect.signature(init).parameters.values():
            if param.name != "self" and param.kind in (param.KEYWORD_ONLY, param.POSITIONAL_OR_KEYWORD):
                keys.add(param.name)
    return sorted(keys | JOB_ATTACK_OPTIONS)


def _refuse(path: str, key: str, allowed: Iterable[str]) -> None:
    allowed = sorted(allowed)
    hint = suggest(key, allowed)
    if not path:
        extra = f"; did you mean [{hint}]?" if hint else ""
        raise ValueError(f"unknown config section [{key}]{extra} (valid sections: {', '.join(allowed)})")
    extra = f"; did you mean {path + '.' + hint!r}?" if hint else ""
    raise ValueError(f"unknown config key {path + '.' + key!r}{extra} (valid keys here: {', '.join(allowed)})")


def _check_table(value: Any, path: str, allowed: Iterable[str]) -> None:
    if not isinstance(value, Mapping):
        raise ValueError(f"config section [{path}] must be a table, got {type(value).__name__}")
    allowed = set(allowed)
    for key in value:
        if key not in allowed:
            _refuse(path, str(key), allowed)


def _check_attack_options(table: Mapping[str, Any], path: str, families: Mapping[str, type]) -> None:
    for perturbation, cls in families.items():
        if perturbation in table:
            _check_table(table[perturbation], f"{path}.{perturbation}", attack_option_keys(cls))


def check_keys(raw: Mapping[str, Any], families: Mapping[str, type]) -> None:
    """Refuse any key of a parsed sweep file that the loader does not read.

    Args:
        raw: the parsed TOML/YAML mapping.
        families: perturbation name -> attack class (``meshadv.attacks.families.PERTURBATIONS``).

    Raises:
        ValueError: the first unknown section or key, with its dotted path and the closest valid key.
    """
    _check_table(raw, "", SECTION_KEYS)
    for section, allowed in SECTION_KEYS.items():
        if section not in raw:
            continue
        extra = set(families) if section == "attack" else set()
        _check_table(raw[section], section, allowed | extra)
    attack = raw.get("attack", {})
    _check_attack_options(attack, "attack", families)
    protocols = attack.get("protocols", {})
    if not isinstance(protocols, Mapping):
        raise ValueError(f"attack.protocols must be a table of named protocols, got {type(protocols).__name__}")
    for name, proto in protocols.items():
        _check_table(proto, f"attack.protocols.{name}", PROTOCOL_KEYS | set(families))
        _check_attack_options(proto, f"attack.protocols.{name}", families)
    for path, stage in _retry_stages(attack):
        _check_table(stage, path, families)
        _check_attack_options(stage, path, families)


def _retry_stages(attack: Mapping[str, Any]) -> List[Tuple[str, Any]]:
    """``(path, table)`` of each retry stage: ``[attack.retry]`` is one, ``[[attack.retry]]`` a list of them."""
    retry = attack.get("retry", {})
    if isinstance(retry, list):
        if len(retry) == 1:
            return [("attack.retry", retry[0])]
        return [(f"attack.retry[{i}]", stage) for i, stage in enumerate(retry)]
    return [("attack.retry", retry)] if retry else []


def check_attack_values(attack: Mapping[str, Any], families: Mapping[str, type]) -> None:
    """Build every attack the sweep will build, so bad option values (``steps = "10"``) fail at load.

    Args:
        attack: the ``[attack]`` table after defaults (``perturbations``, one options table per perturbation,
            ``protocols`` and ``retry``).
        families: perturbation name -> attack class.

    Raises:
        ValueError: the attack class refused an option; the message names the table.
    """
    tables = [("attack", attack)] + [(f"attack.protocols.{n}", p) for n, p in attack.get("protocols", {}).items()]
    # a retry runs with its stage's options over its parent's: the main setting's and the earlier stages'
    options = {p: dict(attack.get(p, {})) for p in families}
    for path, stage in _retry_stages(attack):
        options = {p: {**o, **dict(stage.get(p, {}))} for p, o in options.items()}
        tables.append((path, {p: options[p] for p in stage}))
    for path, table in tables:
        for perturbation in attack.get("perturbations", []):
            options = {k: v for k, v in dict(table.get(perturbation, {})).items() if k not in JOB_ATTACK_OPTIONS}
            try:
                families[perturbation](**options).config()  # config() builds the update rule: method_options
            except (TypeError, ValueError) as exc:
                raise ValueError(f"[{path}.{perturbation}]: {exc}") from None
