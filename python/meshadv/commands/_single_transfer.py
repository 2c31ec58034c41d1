"""Transfer one saved ``meshadv attack`` result (its output folder) to Mitsuba 3: ``meshadv transfer attack DIR``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, List, Optional

if TYPE_CHECKING:
    from meshadv.transfer.results import ControlledResult

__all__ = ["case_from_attack_folder", "transfer_attack_folder", "transfer_attack_summary"]


def case_from_attack_folder(folder: Path) -> Any:
    """The ``TransferCase`` of a saved attack: its first adversarial mesh, its views, victim, classes and setup.

    The benign object's class is the victim's pristine top-1 on the first view (what the attack moved away from);
    the benign mesh (the control rendered by Mitsuba too) is the folder's ``benign.ply``, else the input mesh the
    record names, loaded again.

    Raises:
        FileNotFoundError: ``folder`` holds no ``result.json`` or its mesh is missing.
        ValueError: the result is not a classifier attack.
    """
    from meshadv.attacks.result import load_result_record
    from meshadv.mesh import load_mesh
    from meshadv.transfer.benign_control import benign_mesh_of_attack_folder
    from meshadv.transfer.controlled import TransferCase

    record = load_result_record(folder)
    if not record.get("original_top1_names"):
        raise ValueError(f"{folder}: only classifier attacks can be transferred this way (no top-1 in result.json)")
    mesh_file = Path(folder) / record["meshes"][0][0]
    if not mesh_file.is_file():
        raise FileNotFoundError(f"{mesh_file} is missing: re-run the attack or copy the whole output folder")
    config = record.get("config") or {}
    criterion = record["criteria"][0]
    adversarial = load_mesh(mesh_file)
    return TransferCase(
        case_id="mitsuba",  # the renders are saved as mitsuba_v<view>.png beside result.json
        mesh=adversarial,
        views=tuple(record["views"]),
        victim=record["victim"],
        true_class=record["original_top1_names"][0],
        target=criterion.get("target_class"),
        perturbation=record.get("perturbation", ""),
        image_size=tuple(config.get("image_size") or (224, 224)),
        background=tuple(config.get("background") or (1.0, 1.0, 1.0)),
        benign_correct=None,
        antialias=int(config.get("antialias") or 1),
        benign_mesh=benign_mesh_of_attack_folder(Path(folder), record, int(adversarial.vertices.shape[0])),
    )


def transfer_attack_folder(folder: Path, *, spp: int = 64, max_depth: int = 8, variant: Optional[str] = None,
                           victim_loader: Optional[Callable[[str], Any]] = None) -> List[ControlledResult]:
    """Render ``folder``'s adversarial mesh with Mitsuba under the attack's views and test the victim.

    Writes ``transfer.json`` (one record per view, see ``meshadv.transfer.controlled.evaluate_case``) and the
    Mitsuba renders ``mitsuba_v<view>.png`` (adversarial) and ``mitsuba_benign_v<view>.png`` into ``folder``.

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


def transfer_attack_summary(rows: List["ControlledResult"]) -> str:
    """One line on a transferred attack's views: targeted (or untargeted) success in Mitsuba, and the untargeted
    transfer counted only on the views whose benign Mitsuba render is right (the benign control)."""
    control = [r for r in rows if r.benign_correct_mitsuba]
    untargeted = sum(bool(r.untargeted_mitsuba) for r in control)
    targeted = (f"targeted transfer on {sum(bool(r.success_mitsuba) for r in rows)}/{len(rows)} views; "
                if rows and rows[0].target else "")
    return (f"{targeted}untargeted transfer on {untargeted}/{len(control)} views whose benign Mitsuba render is "
            f"right ({len(rows) - len(control)} left out: the benign mesh is not its class there either)")
