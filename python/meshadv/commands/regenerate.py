"""``meshadv regenerate RESULTS.db JOB -o DIR``: a finished job's artefacts again, from its stored spec and seed."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

__all__ = ["register", "regenerate"]


def regenerate(
    results: Path = typer.Argument(..., help="Results database written by `meshadv sweep`."),
    job: str = typer.Argument(..., help="Job id (or a unique prefix of it)."),
    out: Optional[Path] = typer.Option(None, "-o", "--out",
                                       help="Artefact folder (default: <database folder>/jobs/<id[:2]>/<id>)."),
    threads: int = typer.Option(0, help="Intra-op threads (0 = default)."),
    assume: Optional[Path] = typer.Option(
        None, "--assume", help="JSON file of the sweep's defaults for records that do not pin them "
                               "(meshadv.experiments.regenerate.pinned_spec)."),
) -> None:
    """Re-run one job of RESULTS into a folder (meshes, renders, result.json) and check it reproduces its record."""
    from meshadv.experiments.regenerate import compute_note, load_assumed, regenerate_job

    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist", param_hint="RESULTS")
    try:
        assumed = load_assumed(assume)
    except (FileNotFoundError, ValueError) as err:
        raise typer.BadParameter(str(err), param_hint="--assume") from err
    try:
        done = regenerate_job(results, job, out, threads=threads, assume=assumed)
    except KeyError as err:
        raise typer.BadParameter(str(err.args[0]), param_hint="JOB") from err
    typer.echo(f"job {done.job_id}: artefacts in {done.out_dir}")
    for note in done.notes:
        typer.echo(f"not pinned: {note}", err=True)
    if done.stored is None:
        typer.echo("the database holds no finished record of this job to compare with")
    elif done.matches:
        typer.echo("the regenerated record matches the stored one (success, steps, distance, first successful "
                   "step)")
    else:
        typer.echo("the regenerated record differs from the stored one: " + "; ".join(done.differences), err=True)
        typer.echo(compute_note(done.stored), err=True)
        raise typer.Exit(code=1)


def register(app: typer.Typer) -> None:
    """Add the ``regenerate`` command to ``app``."""
    app.command("regenerate")(regenerate)
