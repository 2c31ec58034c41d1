"""``meshadv report RESULTS.db -o DIR``: write the paper's tables (Markdown, CSV), figures (PNG) and the settings."""

from __future__ import annotations

from pathlib import Path

import typer

__all__ = ["register", "report"]


def report(
    results: Path = typer.Argument(..., help="Results database written by `meshadv sweep`."),
    out: Path = typer.Option(..., "-o", "--out", help="Report folder."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Draw the figures."),
) -> None:
    """Write Table 1, Table 2, the figures and the run's settings from RESULTS."""
    from meshadv.experiments.report import write_report

    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist", param_hint="RESULTS")
    output = write_report(results, out, figures=figures)
    typer.echo(f"wrote {len(output.tables)} table files and {len(output.figures)} figures to {output.out_dir}")


def register(app: typer.Typer) -> None:
    """Add the ``report`` command to ``app``."""
    app.command("report")(report)
