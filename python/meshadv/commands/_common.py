"""Helpers shared by the ``meshadv`` subcommands: mesh arguments, view sets, colours and labels.

Heavy imports (torch, the renderer, victims) happen inside the functions so ``meshadv --help`` stays fast.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any, List, Mapping, Optional, Sequence, Tuple

if TYPE_CHECKING:
    from meshadv.mesh.file_input import MeshInput

__all__ = [
    "DEFAULT_HELD_OUT_FRACTION",
    "VICTIMS",
    "load_mesh_input",
    "parse_azimuth_range",
    "parse_duration",
    "DEFAULT_DISTANCE",
    "DEFAULT_ELEVATION",
    "DEFAULT_BACKGROUND",
    "load_mesh_arg",
    "make_views",
    "parse_color",
    "resolve_method",
    "topk_labels",
]

#: Camera distance that frames a mesh normalised into [-1, 1] (whole object in view) with a 30 degree field of view.
DEFAULT_DISTANCE = 4.5
#: Default camera elevation (degrees).
DEFAULT_ELEVATION = 15.0
#: Default background colour.
DEFAULT_BACKGROUND = "1,1,1"
#: Default ``--held-out-fraction`` of the attack commands: the share of held-out views a SUCCESS must also hold on.
DEFAULT_HELD_OUT_FRACTION = 0.8


#: The victims' names, for ``--victim`` help texts (kept equal to ``meshadv.victims.available_victims()`` by a
#: test; listed here so that ``--help`` does not import torch).
VICTIMS = ("efficientnet_lite0", "efficientnet_lite2", "ssd_mobilenet_v2_coco", "densenet121", "inception_v3",
           "yolov3")


def load_mesh_input(spec: str, *, z_up: Optional[bool] = None, say: bool = True) -> MeshInput:
    """Load the mesh named on the command line and normalise it into ``[-1, 1]``, saying which axis was taken as up.

    Args:
        spec: a mesh file (PLY/OBJ/OFF/STL/glTF), ``builtin:NAME`` (a generated shape) or ``default`` (the shared
            PASCAL3D+ default when present, else a built-in).
        z_up: the file is Z-up (rotate to Y-up); ``None`` guesses True for files under a ``pascal3d`` folder and
            prints the guess and how to change it (``--z-up`` / ``--y-up``) on stderr.
        say: print that note.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unknown built-in name or unreadable mesh.
    """
    import typer

    from meshadv.mesh.file_input import MeshInput, read_file_input
    from meshadv.mesh.shapes import builtin_mesh, default_mesh

    if spec == "default":
        return MeshInput(default_mesh(), "default", None, None, False)
    if spec.startswith("builtin:"):
        return MeshInput(builtin_mesh(spec.split(":", 1)[1]), spec, None, None, False)
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"MESH {spec} does not exist (give a mesh file, builtin:NAME or default)")
    if z_up is None:
        z_up = "pascal3d" in (p.lower() for p in path.resolve().parts)
        if say:
            why = "its path has a 'pascal3d' folder" if z_up else "the renderer's convention"
            other = "--y-up" if z_up else "--z-up"
            typer.echo(f"note: {path.name} taken as {'Z' if z_up else 'Y'}-up ({why}); if it renders lying on its "
                       f"side or back, pass {other}", err=True)
    return read_file_input(path, z_up=bool(z_up), label=str(path))


def load_mesh_arg(spec: str, *, z_up: Optional[bool] = None) -> Tuple[Any, str]:
    """``(mesh, label)`` of :func:`load_mesh_input` (the normalised mesh and how the command line named it)."""
    loaded = load_mesh_input(spec, z_up=z_up)
    return loaded.mesh, loaded.label


def parse_azimuth_range(text: str, name: str = "--azimuths") -> Tuple[float, float]:
    """``"LOW:HIGH"`` or ``"LOW-HIGH"`` (degrees, LOW <= HIGH; negative values allowed, e.g. ``-30:30``).

    Raises:
        ValueError: anything else (the message names ``name``).
    """
    match = re.fullmatch(r"\s*(-?\d+(?:\.\d*)?)\s*[:-]\s*(-?\d+(?:\.\d*)?)\s*", text)
    if match is None:
        raise ValueError(f"{name} must be a range LOW:HIGH or LOW-HIGH in degrees (e.g. 150:210), got {text!r}")
    lo, hi = float(match.group(1)), float(match.group(2))
    if hi < lo:
        raise ValueError(f"{name} must have LOW <= HIGH, got {text!r}")
    return lo, hi


def parse_duration(text: str, name: str) -> float:
    """Seconds of a duration written ``90m``, ``2h``, ``1h30m``, ``45s`` or a bare number of seconds (``3600``).

    Raises:
        ValueError: anything else (the message names ``name``).
    """
    number = r"(\d+(?:\.\d*)?|\.\d+)"
    match = re.fullmatch(rf"\s*(?:{number}\s*h)?\s*(?:{number}\s*m)?\s*(?:{number}\s*s?)?\s*", text)
    if match is None or not any(match.groups()):
        raise ValueError(f"{name} must be a duration such as 90m, 2h, 1h30m, 45s or a number of seconds, got {text!r}")
    hours, minutes, seconds = (float(g) if g else 0.0 for g in match.groups())
    return hours * 3600.0 + minutes * 60.0 + seconds


def make_views(
    num_views: int,
    azimuth_range: Sequence[float] = (150.0, 210.0),
    elevation: float = DEFAULT_ELEVATION,
    distance: float = DEFAULT_DISTANCE,
    offset: float = 0.0,
) -> Any:
    """``num_views`` azimuths evenly spread over ``azimuth_range`` (inclusive; one view sits at its centre).

    Args:
        num_views: number of views (>= 1).
        azimuth_range: ``(low, high)`` degrees.
        elevation: camera elevation in degrees.
        distance: camera distance.
        offset: shift every azimuth by this fraction of the spacing (0.5 puts held-out views between the
            optimised ones).

    Returns:
        A ``ViewSet`` with a head light per view.

    Raises:
        ValueError: ``num_views < 1`` or an empty range.
    """
    import torch

    from meshadv.render import ViewSet

    if num_views < 1:
        raise ValueError(f"views must be >= 1, got {num_views}")
    lo, hi = float(azimuth_range[0]), float(azimuth_range[1])
    if hi < lo:
        raise ValueError(f"azimuth range must be (low, high) with low <= high, got {azimuth_range}")
    if num_views == 1:
        az = torch.tensor([(lo + hi) / 2])
    else:
        az = torch.linspace(lo, hi, num_views)
        if offset:
            step = (hi - lo) / (num_views - 1)
            az = (az + offset * step)[:-1] if offset > 0 else az
    return ViewSet.orbit(az, elevation=elevation, distance=distance)


def parse_color(text: str, name: str = "background") -> Tuple[float, float, float]:
    """Parse ``"r,g,b"`` (floats in [0, 1]) or a grey level ``"g"``.

    Raises:
        ValueError: not 1 or 3 numbers in ``[0, 1]``.
    """
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"{name} must be 'r,g,b' or a grey level in [0, 1], got {text!r}") from None
    if len(values) == 1:
        values = values * 3
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError(f"{name} must be 'r,g,b' or a grey level in [0, 1], got {text!r}")
    return values[0], values[1], values[2]


def topk_labels(logits: Any, names: Sequence[str], k: int = 5) -> List[List[Tuple[str, float]]]:
    """Top-``k`` ``(name, probability)`` pairs of each row of ``(B, C)`` logits."""
    import torch

    probs = torch.softmax(logits.detach().float(), dim=1)
    values, idx = probs.topk(min(k, probs.shape[1]), dim=1)
    return [[(names[int(i)] if int(i) < len(names) else str(int(i)), float(v)) for v, i in zip(vr, ir)]
            for vr, ir in zip(values.tolist(), idx.tolist())]


def resolve_method(method: Optional[str], default: str, adam_only: Mapping[str, bool]) -> str:
    """The update rule a command runs: ``--method``, else ``default``.

    Args:
        method: the ``--method`` option (``None``: not given).
        default: the command's default rule.
        adam_only: each option that only the paper's Adam has (flag name -> whether the user gave it).

    Raises:
        ValueError: an unknown rule, or one of ``adam_only`` given with another rule.
    """
    from meshadv.attacks.update import update_rules

    method = default if method is None else method
    if method not in update_rules():
        raise ValueError(f"--method must be one of {sorted(update_rules())}, got {method!r}")
    given = [flag for flag, is_given in adam_only.items() if is_given]
    if method != "adam" and given:
        raise ValueError(f"{', '.join(given)} apply to --method adam only")
    return method
