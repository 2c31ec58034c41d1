"""What ``meshadv attack`` does with the benign check (:mod:`meshadv.attacks.benign`) before it attacks: refuse (or,
when told to go on, warn) when the benign render is not the source class on some views, leave out targets that
already hold, and stop with "nothing to do" when every target does."""

from __future__ import annotations

from typing import Any, List, Optional, Sequence

import typer

__all__ = ["benign_gate", "source_class"]


def source_class(explicit: Optional[str], untargeted: Optional[str], path: Any) -> Optional[str]:
    """The class the benign mesh should be: ``--source``, else ``--untargeted``'s class, else the PASCAL3D+ class of
    a mesh under a ``pascal3d/<class>/`` folder, else ``None`` (unknown: not checked)."""
    if explicit:
        return explicit
    if untargeted:
        return untargeted
    from meshadv.attacks.benign import source_class_of_path
    from meshadv.data import PASCAL3D_CLASSES

    return source_class_of_path(path, PASCAL3D_CLASSES)


def benign_gate(mesh: Any, views: Any, victim: Any, criteria: Sequence[Any], *, source: Optional[str], setup: Any,
                success_fraction: float, go_on: bool) -> List[Any]:
    """Check the benign mesh on the attack's views and return the criteria still worth attacking.

    Prints the benign top-1 per view; when the render is not ``source`` (its top-1 outside ``source``'s class group,
    :func:`meshadv.attacks.criteria.resolve_true_class`) on some views, ends the command with exit
    status 1 unless ``go_on`` (then it warns); prints which targets already hold and leaves them out; ends with exit
    status 0 and "nothing to do" when every target already holds.

    Raises:
        typer.Exit: refused (1) or nothing to do (0).
    """
    from meshadv.attacks.benign import check_benign

    check = check_benign(mesh, views, victim, criteria, source=source, setup=setup,
                         success_fraction=success_fraction)
    if check.top1:
        typer.echo("benign top-1 per view: " + ", ".join(check.top1))
    if check.wrong_views:
        message = (f"the benign render is not {check.describe_source()} on {check.describe_wrong()} of the "
                   f"{len(views)} attack views: "
                   "an attack there shows nothing about the victim")
        if not go_on:
            typer.echo(f"Error: {message}; pass --benign-wrong-ok to attack anyway (or --source CLASS if the mesh is "
                       "another class)", err=True)
            raise typer.Exit(code=1)
        typer.echo(f"warning: {message}", err=True)
    held = check.already_held
    labels = [c.label for c in criteria]
    if all(held):
        typer.echo(f"nothing to do: {', '.join(labels)} already hold{'s' if len(labels) == 1 else ''} on the benign "
                   f"mesh (on at least {success_fraction:.0%} of the {len(views)} views); no attack run")
        raise typer.Exit(code=0)
    if any(held):
        left_out = ", ".join(name for name, h in zip(labels, held) if h)
        typer.echo(f"already hold on the benign mesh, left out: {left_out}")
    return [c for c, h in zip(criteria, held) if not h]
