"""Transfer one saved ``meshadv attack`` result (its output folder) to Mitsuba 3: ``meshadv transfer attack DIR``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, List, Optional

if TYPE_CHECKING:
    from meshadv.transfer.results import ControlledResult

__all__ = ["case_from_attack_folder", "transfer_attack_folder"]


def case_from_attack_folder(folder: Path) -> Any:
    """The ``TransferCase`` of a saved attack: its first adversarial mesh, its views, victim, classes and setup.

    The benign object's class is the victim's pristine top-1 on the first view (what the attack moved away from).

    Raises:
        FileNotFoundError: ``folder`` holds no ``result.json`` or its mesh is missing.
        ValueError: the result is not a classifier attack.
    """
    from meshadv.attacks.result import load_result_record
    from meshadv.mesh import load_mesh
    from meshadv.transfer.controlled import TransferCase

    record = load_result_record(folder)
    if not record.get("original_top1_names"):
        raise ValueError(f"{folder}: only classifier attacks can be transferred this way (no top-1 in result.json)")
    mesh_file = Path(folder) / record["meshes"][0][0]
    if not mesh_file.is_file():
        raise FileNotFoundError(f"{mesh_file} is missing: re-run the attack or copy the whole output folder")
    config = record.get("config") or {}
    criterion = record["criteria"][0]
    return TransferCase(
        case_id="mitsuba",  # the renders are saved as mitsuba_v<view>.png beside result.json
        mesh=load_mesh(mesh_file),
        views=tuple(record["views"]),
        victim=record["victim"],
        true_class=record["original_top1_names"][0],
        target=criterion.get("target_class"),
        perturbation=record.get("perturbation", ""),
        image_size=tuple(config.get("image_size") or (224, 224)),
        background=tuple(config.get("background") or (1.0, 1.0, 1.0)),
        benign_correct=None,
        antialias=int(config.get("antialias") or 1),
    )


def transfer_attack_folder(folder: Path, *, spp: int = 64, max_depth: int = 8, variant: Optional[str] = None,
                           victim_loader: Optional[Callable[[str], Any]] = None) -> List[ControlledResult]:
    """Render ``folder``'s adversarial mesh with Mitsuba under the attack's views and test the victim.

    Writes ``transfer.json`` (one record per view, see ``meshadv.transfer.controlled.evaluate_case``) and the
    Mitsuba renders ``mitsuba_v<view>.png`` into ``folder``.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per view.

    Raises:
        FileNotFoundError / ValueError: see :func:`case_from_attack_folder`.
        ModuleNotFoundError: Mitsuba 3 is not installed (``pip install 'meshadv[transfer]'``).
    """
    import mitsuba  # noqa: F401  (a clear ModuleNotFoundError before any work)

    from meshadv.transfer.controlled import controlled_transfer
    from meshadv.util.atomic import write_json_atomic

    case = case_from_attack_folder(folder)
    rows = controlled_transfer([case], spp=spp, max_depth=max_depth, variant=variant, victim_loader=victim_loader,
                               image_dir=folder, on_error="raise")
    write_json_atomic({"folder": str(Path(folder).resolve()), "spp": spp, "max_depth": max_depth,
                       "rows": [row.to_record() for row in rows]}, Path(folder) / "transfer.json")
    return rows
