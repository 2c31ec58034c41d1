"""``meshadv report RESULTS.db -o DIR``: write the paper's tables (Markdown, CSV), figures (PNG) and the settings."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Optional

import typer

__all__ = ["register", "report", "write_full_report"]


def write_full_report(results: Path, out: Path, *, figures: bool = True, artifacts: Optional[Path] = None,
                      use_stored: bool = True, threads: int = 1, assume: Optional[Dict[str, Any]] = None,
                      redraw: bool = False) -> object:
    """The sweep report with what other packages add: the Mitsuba transfer section (rows of ``meshadv transfer``
    in the same database) and the perceptual proxies (SSIM / PSNR, ``proxies.csv``). ``artifacts``, ``use_stored``,
    ``threads`` and ``assume``: where the figures' artefacts come from; ``redraw``: draw figures that are up to
    date too (``meshadv.experiments.report.write_report``).

    Returns:
        The :class:`~meshadv.experiments.report.ReportOutput`.

    Raises:
        FileNotFoundError: ``results`` does not exist.
    """
    from meshadv.experiments.report import write_report
    from meshadv.study.proxies import proxy_section
    from meshadv.transfer.results import load_transfer_rows, transfer_report

    def proxies(rows: list, out_dir: Path) -> tuple:
        text = proxy_section(rows, out_dir)
        return text, [out_dir / "proxies.csv"] if text else []

    rows = load_transfer_rows(results) if Path(results).is_file() else []
    return write_report(results, out, figures=figures, transfer_rows=rows, transfer_section=transfer_report,
                        sections=[proxies],
                        artifacts=artifacts, use_stored=use_stored, threads=threads, assume=assume, redraw=redraw)


def report(
    results: Path = typer.Argument(..., help="Results database written by `meshadv sweep`."),
    out: Path = typer.Option(..., "-o", "--out", help="Report folder."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Draw the figures."),
    artifacts: Optional[Path] = typer.Option(
        None, "--artifacts", help="Regenerate the artefacts the figures need (only the jobs a figure uses) into this "
                                  "folder when they are not on this machine, and check them against the database "
                                  "(regeneration.md)."),
    stored: bool = typer.Option(True, "--stored/--no-stored",
                                help="Use the artefact folders the database records (--no-stored with --artifacts: "
                                     "every figure from regenerated artefacts)."),
    threads: int = typer.Option(1, help="Intra-op threads of each regeneration."),
    assume: Optional[Path] = typer.Option(
        None, "--assume", help="JSON file of the sweep's defaults for records that do not pin them "
                               "(meshadv.experiments.regenerate.pinned_spec)."),
    redraw: bool = typer.Option(False, "--redraw", help="Draw every figure again (by default a grid or flow figure "
                                "already in the report folder, drawn from the same jobs and outcomes, is kept and "
                                "its artefacts are not regenerated)."),
) -> None:
    """Write Table 1, Table 2, the figures and the run's settings from RESULTS; index.csv / index.md map the job
    folders (named by hash) to their settings; failed jobs' errors are printed."""
    from meshadv.commands._job_index import failed_jobs, warn_damaged_results, write_job_index
    from meshadv.experiments import ResultStore
    from meshadv.experiments.regenerate import load_assumed

    if results.suffix.lower() in (".toml", ".yaml", ".yml"):
        raise typer.BadParameter(f"{results} is a sweep config, not a results database: run `meshadv sweep "
                                 f"{results}` first, then `meshadv report {_database_of(results)} -o {out}`",
                                 param_hint="RESULTS")
    if results.is_dir():
        raise typer.BadParameter(f"{results} is a folder; give the results.db file in it", param_hint="RESULTS")
    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist (give the results.db that `meshadv sweep` wrote)",
                                 param_hint="RESULTS")
    with ResultStore(results, read_only=True) as store:  # a file that is not a results database fails here, in one line
        failed = failed_jobs(store)
        index = write_job_index(store, out, results.parent)  # the default config puts the db in the output folder
        warn_damaged_results(store, results)
    if threads < 1:
        raise typer.BadParameter(f"must be >= 1, got {threads}", param_hint="--threads")
    if not stored and artifacts is None:
        raise typer.BadParameter("--no-stored needs --artifacts (where to regenerate)", param_hint="--no-stored")
    try:
        assumed = load_assumed(assume)
    except (FileNotFoundError, ValueError) as err:
        raise typer.BadParameter(str(err), param_hint="--assume") from err
    try:
        output = write_full_report(results, out, figures=figures, artifacts=artifacts, use_stored=stored,
                                   threads=threads, assume=assumed, redraw=redraw)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: every finished regeneration is complete in --artifacts
        if artifacts is None:
            raise
        from meshadv.commands._common_options import interrupted_exit

        raise interrupted_exit(f"interrupted: the jobs regenerated so far are kept in {artifacts}; run the same "
                               "command again and only the others are regenerated") from None
    typer.echo(f"wrote {len(output.tables)} table files and {len(output.figures)} figures to {output.out_dir}")
    typer.echo(f"job index (job id -> folder, settings, state): {index}")
    regen = getattr(output, "regenerations", {})
    if regen:
        same = sum(1 for c in regen.values() if c.get("matches"))
        typer.echo(f"regenerated {len(regen)} job(s) for the figures; {same} reproduce their stored record "
                   f"(regeneration.md)")
    if failed:
        typer.echo(f"{len(failed)} job(s) failed:", err=True)
        for job in failed[:10]:
            typer.echo(f"  {job['job_id'][:12]} ({job['attempts']} attempts): {job['error']}", err=True)
        if len(failed) > 10:
            typer.echo(f"  ... {len(failed) - 10} more in {index}", err=True)


def _database_of(config: Path) -> str:
    """The results database a sweep config names (``<output>/results.db`` by default), or a placeholder."""
    try:
        from meshadv.experiments.config import load_config

        return str(load_config(config).db)
    except Exception:  # noqa: BLE001 - only for the hint of an error message
        return "RESULTS.db"


def register(app: typer.Typer) -> None:
    """Add the ``report`` command to ``app``."""
    app.command("report")(report)
