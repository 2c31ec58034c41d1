"""Sweep configs name the attack families ``perturbations``; the old key ``types`` is still read."""

from __future__ import annotations

import pytest

from meshadv.experiments.config import expand_jobs, parse_config


def _raw(attack: dict) -> dict:
    return {"meshes": {"source": "builtin", "builtin": [{"name": "chair", "class": "chair"},
                                                        {"name": "sofa", "class": "sofa"}]},
            "victims": {"names": ["v"]}, "render": {"configurations": 1}, "attack": attack}


def test_new_and_old_key_give_the_same_jobs() -> None:
    new = expand_jobs(parse_config(_raw({"perturbations": ["texture"]})))
    old = expand_jobs(parse_config(_raw({"types": ["texture"]})))
    assert new == old and {j["perturbation"] for j in new} == {"texture"}


def test_both_keys_or_an_unknown_perturbation_are_refused() -> None:
    with pytest.raises(ValueError, match="attack.types is the old name of attack.perturbations"):
        parse_config(_raw({"types": ["shape"], "perturbations": ["shape"]}))
    with pytest.raises(ValueError, match="attack.perturbations must be"):
        parse_config(_raw({"perturbations": ["colour"]}))
