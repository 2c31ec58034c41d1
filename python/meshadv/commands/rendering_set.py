"""``meshadv rendering-set build|report``: the "PASCAL3D+ renderings" set (views every victim classifies right).

``build`` samples camera and lighting configurations per class until ``--per-class`` of them are classified correctly
by every victim (resumable: run it again after a kill), ``report`` writes the pass-rate table (Markdown) and a
contact sheet of kept renders. See :mod:`meshadv.datasets.rendering_set` for the sampling law and the file format.

Example:
    $ meshadv rendering-set build -o data/pascal3d_renderings_v1.json
    $ meshadv rendering-set report data/pascal3d_renderings_v1.json -o docs/results/rendering_set
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Any, Optional

import typer

__all__ = ["build", "register", "report"]

DEFAULT_VICTIMS = "efficientnet_lite0,efficientnet_lite2"


def _split(value: str) -> list[str]:
    return [part.strip() for part in value.split(",") if part.strip()]


def build(
    out: Path = typer.Option(..., "-o", "--out", help="The rendering-set JSON file (resumed when it exists)."),
    victims: str = typer.Option(DEFAULT_VICTIMS, help="Comma-separated victim names that must all be right."),
    per_class: int = typer.Option(72, help="Kept renderings per class (the paper: 72)."),
    seed: int = typer.Option(0, help="Master seed."),
    classes: Optional[str] = typer.Option(None, help="Comma-separated classes (default: all 7)."),
    pascal3d: Optional[Path] = typer.Option(None, help="PASCAL3D+ folder (default: the shared data's)."),
    max_candidates: int = typer.Option(0, help="Give up on a class after this many candidates (0 = 50 x per-class)."),
    batch_size: int = typer.Option(16, help="Candidates rendered and classified together."),
) -> None:
    """Build (or resume) the PASCAL3D+ rendering set and print its pass rates."""
    from meshadv.data import shared_data_dir
    from meshadv.datasets.rendering_set import (
        RenderingSetConfig,
        build_rendering_set,
        pascal3d_mesh_paths,
        pass_rate_table,
    )

    try:
        paths = pascal3d_mesh_paths(pascal3d, _split(classes) if classes else None)
    except (FileNotFoundError, ValueError) as err:
        raise typer.BadParameter(str(err), param_hint="--pascal3d / --classes") from err
    mesh_root = pascal3d.resolve().parent if pascal3d is not None else shared_data_dir()

    def progress(cls: str, stats: dict[str, Any]) -> None:
        typer.echo(f"{cls}: kept {stats['kept']}/{per_class} of {stats['tried']} tried", err=True)

    try:
        doc = build_rendering_set(
            paths,
            _split(victims),
            per_class,
            seed,
            out,
            config=RenderingSetConfig(max_candidates_per_class=max_candidates),
            batch_size=batch_size,
            mesh_root=mesh_root,
            progress=progress,
        )
    except (FileNotFoundError, ValueError) as err:
        raise typer.BadParameter(str(err)) from err
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the file holds every finished batch (written atomically)
        from meshadv.commands._common_options import interrupted_exit

        kept = f"the finished batches are kept in {out}" if out.is_file() else "no batch had finished"
        raise interrupted_exit(f"interrupted: {kept}; run the same command again to resume") from None
    typer.echo(pass_rate_table(doc))
    short = [c for c, s in doc["classes"].items() if s["kept"] < per_class]
    typer.echo(f"wrote {out} ({len(doc['renderings'])} renderings)" + (f"; short: {', '.join(short)}" if short else ""))


def report(
    rendering_set: Path = typer.Argument(..., help="A rendering-set JSON file."),
    out: Path = typer.Option(..., "-o", "--out", help="Report folder (pass_rates.md, contact_sheet.png)."),
    per_class: int = typer.Option(8, help="Renders per class on the contact sheet."),
    mesh_root: Optional[Path] = typer.Option(None, help="Folder of the set's relative mesh paths (default: shared)."),
) -> None:
    """Write the pass-rate table and a contact sheet (rows = classes) of a rendering set."""
    from meshadv.datasets.rendering_set import load_rendering_set, pass_rate_table, render_records
    from meshadv.datasets.rendering_set_sheet import contact_sheet
    from meshadv.util.atomic import write_text_atomic

    try:
        doc = load_rendering_set(rendering_set)
    except (FileNotFoundError, ValueError) as err:
        raise typer.BadParameter(str(err), param_hint="RENDERING_SET") from err
    out.mkdir(parents=True, exist_ok=True)
    table = pass_rate_table(doc, markdown=True)
    command = "meshadv rendering-set report " + " ".join(shlex.quote(a) for a in sys.argv[3:])
    intro = f"Pass rates recorded in `{rendering_set.name}` by its build (this file: `{command}`):"
    write_text_atomic(out / "pass_rates.md", f"{intro}\n\n{table}\n")
    rows = {}
    for cls in doc["classes"]:
        records = [r for r in doc["renderings"] if r["class"] == cls][:per_class]
        if records:
            rows[cls] = render_records(doc, records, mesh_root)
    if rows:
        contact_sheet(rows, out / "contact_sheet.png")
    typer.echo(table)
    typer.echo(f"wrote {out / 'pass_rates.md'}" + (f" and {out / 'contact_sheet.png'}" if rows else ""))


def register(app: typer.Typer) -> None:
    """Add the ``rendering-set`` command group to ``app``."""
    group = typer.Typer(help="The PASCAL3D+ rendering set: build it, report its pass rates.", no_args_is_help=True)
    group.command("build")(build)
    group.command("report")(report)
    app.add_typer(group, name="rendering-set")
