"""The perceptibility cap: ceilings on the measures a person sees, which an attack's success must stay inside.

A :class:`PerceptibilityCap` holds a ceiling per measure of :mod:`meshadv.perceptibility.geometry` (``None``: no
ceiling on it): the largest vertex move as a fraction of the bounding-box diagonal, the area-weighted 95th-percentile
change of the face normals in degrees, the length-weighted 95th-percentile and the largest strain of the edges, and
the area-weighted 95th-percentile change of the face colours. The attack loop projects its flow onto the
largest-move ceiling (:mod:`meshadv.attacks.move_limit`); the others are verdict checks on every step's mesh. An attack
run under a cap counts a step as a success only when the step's mesh is inside it, keeps (when no step succeeds) the
closest step inside it, and reports a final mesh outside it as failed.

:data:`DEFAULT_CAP` is the cap of the command line and of :func:`recommended_cap`, chosen by looking at renders of
attacked PASCAL3D+ meshes (benchmarks/RESULTS.md, "Perceptibility cap").

Example:
    >>> cap = PerceptibilityCap(max_displacement=0.02, normal_change_p95_deg=None, color_change_p95=None)
    >>> cap.violations({"max_displacement": 0.13})
    ['max_displacement 0.13 > 0.02']
    >>> PerceptibilityCap.parse("max_displacement=0.05").max_displacement
    0.05
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Mapping, Optional, Union

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.perceptibility.geometry import color_changes, edge_strains, normal_changes, texel_changes, vertex_moves

__all__ = ["CAP_SLACK", "PerceptibilityCap", "DEFAULT_CAP", "NO_CAP", "recommended_cap", "step_measures", "as_cap"]

#: Relative slack of the ceilings' comparisons (float rounding between the loop's check and the result's measures).
CAP_SLACK = 1e-5


@dataclass(frozen=True)
class PerceptibilityCap:
    """Ceilings on the perceptibility measures (``None``: that measure is not bounded).

    Attributes:
        max_displacement: largest vertex move / the pristine bounding-box diagonal, ``> 0``.
        normal_change_p95_deg: area-weighted 95th-percentile turn of the face normals, degrees in ``(0, 180]``.
        edge_strain_p95: length-weighted 95th-percentile relative change of the edge lengths ``|l' / l - 1|``,
            ``> 0`` (:func:`~meshadv.perceptibility.geometry.edge_strains`; a verdict check, not projected onto).
        edge_strain_max: the largest change of one edge's length relative to that length, or to 0.25% of the
            diagonal where the edge is shorter, ``> 0`` (a thin part torn open; a verdict check).
        color_change_p95: area-weighted 95th-percentile RGB change of the face colours, in ``(0, sqrt(3)]``.

    Raises:
        TypeError / ValueError: a ceiling that is not a number in its range, naming it.
    """

    max_displacement: Optional[float] = None
    normal_change_p95_deg: Optional[float] = None
    edge_strain_p95: Optional[float] = None
    color_change_p95: Optional[float] = None
    edge_strain_max: Optional[float] = None

    def __post_init__(self) -> None:
        highs = {"max_displacement": None, "normal_change_p95_deg": 180.0, "edge_strain_p95": None,
                 "color_change_p95": math.sqrt(3.0), "edge_strain_max": None}
        for name, high in highs.items():
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _validate.positive_float(name, value, high=high))

    @property
    def limits(self) -> Dict[str, float]:
        """The bounded measures and their ceilings."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    @property
    def bounds_anything(self) -> bool:
        """Whether any measure is bounded."""
        return bool(self.limits)

    def admits(self, measures: Mapping[str, Any]) -> Any:
        """Whether ``measures`` (floats or ``(K,)`` tensors per measure, :func:`step_measures`) lie inside every
        ceiling, up to a relative :data:`CAP_SLACK` (so that one mesh measured in float32 and in float64 gets one
        verdict): a bool, or a bool tensor like the measures. A bounded measure missing from ``measures`` or ``nan``
        is not inside."""
        inside: Any = True
        for name, ceiling in self.limits.items():
            value = measures.get(name)
            if value is None:
                return False if not isinstance(inside, Tensor) else torch.zeros_like(inside)
            bound = ceiling * (1.0 + CAP_SLACK)
            ok = value <= bound if isinstance(value, Tensor) else (float(value) <= bound)
            inside = ok & inside if isinstance(ok, Tensor) else (bool(ok) and inside)
        return inside

    def violations(self, measures: Mapping[str, Any]) -> List[str]:
        """``"<measure> <value> > <ceiling>"`` for every ceiling one mesh's ``measures`` exceed (or lack)."""
        out = []
        for name, ceiling in self.limits.items():
            value = measures.get(name)
            if value is None or not float(value) <= ceiling * (1.0 + CAP_SLACK):
                out.append(f"{name} {'missing' if value is None else format(float(value), '.3g')} > {ceiling:g}")
        return out

    def to_record(self) -> Dict[str, Optional[float]]:
        """The ceilings as a JSON-able dict (every field, ``None`` where unbounded)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> "PerceptibilityCap":
        """The cap of :meth:`to_record` (unknown keys are an error).

        Raises:
            ValueError: a key that is not a ceiling's name.
        """
        if not isinstance(record, Mapping):
            raise TypeError(f"a perceptibility cap record must be a dict, got {type(record).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = set(record) - known
        if unknown:
            raise ValueError(f"perceptibility cap has unknown keys {sorted(map(str, unknown))}; known: "
                             f"{sorted(known)}")
        return cls(**dict(record))

    @classmethod
    def parse(cls, text: str) -> "PerceptibilityCap":
        """The cap of a command-line value: ``"none"`` (no ceiling), ``"default"`` (:data:`DEFAULT_CAP`), or
        ``"NAME=VALUE,..."`` (ceilings not named are unbounded; ``NAME=none`` unbounds one explicitly).

        Raises:
            ValueError: an unknown name or a value that is not a positive number, naming it.
        """
        text = str(text).strip()
        if text.lower() in ("none", "off", "0"):
            return NO_CAP
        if text.lower() == "default":
            return DEFAULT_CAP
        values: Dict[str, Optional[float]] = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, sep, value = part.partition("=")
            if not sep:
                raise ValueError(f"cap entry {part!r} must be NAME=VALUE (names: {sorted(DEFAULT_CAP.to_record())})")
            try:
                values[name.strip()] = None if value.strip().lower() == "none" else float(value)
            except ValueError:
                raise ValueError(f"cap entry {part!r}: {value!r} is not a number") from None
        return cls.from_record(values)

    def describe(self) -> str:
        """One line for summaries: ``"max_displacement <= 0.02, normal_change_p95_deg <= 25"`` or ``"none"``."""
        return ", ".join(f"{k} <= {v:g}" for k, v in self.limits.items()) or "none"


#: No ceiling at all (the paper's protocol).
NO_CAP = PerceptibilityCap()

#: The cap of ``meshadv attack``, ``demo``, ``attack-scene`` and sweeps unless they are told otherwise.
DEFAULT_CAP = PerceptibilityCap(max_displacement=0.02, normal_change_p95_deg=25.0, edge_strain_p95=0.085,
                                color_change_p95=0.05, edge_strain_max=1.0)


def recommended_cap(perturbation: str) -> PerceptibilityCap:
    """The cap recommended with an attack of ``perturbation`` (``"shape"`` or ``"texture"``): :data:`DEFAULT_CAP`
    (a texture attack moves no vertex, so its shape ceilings never bind; a shape attack changes no colour)."""
    if perturbation not in ("shape", "texture"):
        raise ValueError(f"perturbation must be 'shape' or 'texture', got {perturbation!r}")
    return DEFAULT_CAP


def as_cap(value: Union[None, PerceptibilityCap, Mapping[str, Any], str], name: str = "perceptibility_cap"
           ) -> Optional[PerceptibilityCap]:
    """``value`` as a cap: ``None`` stays ``None`` (no cap), a cap stays, a dict is :meth:`~PerceptibilityCap.
    from_record`, a string is :meth:`~PerceptibilityCap.parse`; a cap that bounds nothing becomes ``None``.

    Raises:
        TypeError: another type, naming ``name``.
    """
    if value is None:
        return None
    if isinstance(value, str):
        cap = PerceptibilityCap.parse(value)
    elif isinstance(value, PerceptibilityCap):
        cap = value
    elif isinstance(value, Mapping):
        cap = PerceptibilityCap.from_record(value)
    else:
        raise TypeError(f"{name} must be a PerceptibilityCap, a dict of ceilings, a string or None, got "
                        f"{type(value).__name__}")
    return cap if cap.bounds_anything else None


def step_measures(cap: PerceptibilityCap, vertices_adv: Tensor, colors_adv: Any, vertices: Tensor,
                  colors: Tensor, faces: Tensor, texture: Optional[Tensor] = None) -> Dict[str, Tensor]:
    """The measures ``cap`` bounds, for a batch of ``K`` adversarial meshes (the attack loop's per-step check).

    Args:
        cap: the cap (only its bounded measures are computed).
        vertices_adv: ``(K, N, 3)`` adversarial vertices.
        colors_adv: ``(K, M, 3)`` or shared ``(M, 3)`` adversarial face colours, or a reflectance with a
            ``texture`` of shape ``(K, Ht, Wt, 3)`` (a texture-image attack: its colour change is over texels).
        vertices: ``(N, 3)`` pristine vertices.
        colors: ``(M, 3)`` pristine face colours.
        faces: int ``(M, 3)``.
        texture: ``(Ht, Wt, 3)`` pristine texture; required when ``colors_adv`` carries a texture.

    Returns:
        ``{measure: (K,)}``.

    Raises:
        ValueError: ``colors_adv`` carries a texture and ``texture`` is None.
    """
    limits = cap.limits
    out: Dict[str, Tensor] = {}
    with torch.no_grad():
        if "max_displacement" in limits:
            out["max_displacement"] = vertex_moves(vertices_adv, vertices)["max_displacement"]
        if "normal_change_p95_deg" in limits:
            out["normal_change_p95_deg"] = normal_changes(vertices_adv, vertices, faces)["normal_change_p95_deg"]
        if "edge_strain_p95" in limits or "edge_strain_max" in limits:
            strains = edge_strains(vertices_adv, vertices, faces)
            out.update({k: v for k, v in strains.items() if k in limits})
        if "color_change_p95" in limits and not isinstance(colors_adv, Tensor):
            if texture is None:
                raise ValueError("texture (the pristine texture) is required to cap a texture image's change")
            out["color_change_p95"] = texel_changes(colors_adv.texture, texture)["color_change_p95"]
        elif "color_change_p95" in limits:
            batch = colors_adv if colors_adv.dim() == 3 else colors_adv.unsqueeze(0).expand(
                vertices_adv.shape[0], -1, -1)
            out["color_change_p95"] = color_changes(batch, colors, vertices, faces)["color_change_p95"]
    return out
