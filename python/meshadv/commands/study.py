"""``meshadv study export|analyze``: the human perceptual study (2AFC web page) and the analysis of its answers."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

__all__ = ["register", "export", "analyze"]


def export(
    results: Path = typer.Argument(..., help="Results database written by `meshadv sweep`."),
    out: Path = typer.Option(..., "-o", "--out", help="Study folder to write (HTML page, script, images, plan)."),
    per_image: int = typer.Option(5, "--per-image", min=1, help="Answers each image gets (the paper: 5)."),
    max_trials: int = typer.Option(50, "--max-trials", min=1,
                                   help="Most trials per participant, attention checks included (the paper: 50)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the control sample, assignment and orders."),
    controls: int = typer.Option(0, "--controls", min=0, help="Benign renders shown as controls."),
    attention_checks: int = typer.Option(0, "--attention-checks", min=0,
                                         help="Obvious pictures (a written class name) each participant sees."),
    max_images: Optional[int] = typer.Option(None, "--max-images", min=1,
                                             help="Show at most this many attacks (a seeded sample); default all."),
    post_url: Optional[str] = typer.Option(None, "--post-url", help="POST the answers here at the end."),
    post_mode: str = typer.Option("json", "--post-mode",
                                  help="json: fetch with the JSON answers; form: a form POST (answers, assignmentId)."),
    exposure_ms: float = typer.Option(2000.0, "--exposure-ms", help="How long each image is shown (the paper: 2000)."),
    image_px: int = typer.Option(299, "--image-px", min=1, help="Image side on screen in CSS pixels."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing study folder."),
) -> None:
    """Write a static 2AFC study page (open OUT/index.html?participant=N) from RESULTS' successful attacks."""
    from meshadv.study.export import export_study

    if not results.is_file():
        raise typer.BadParameter(f"{results} does not exist", param_hint="RESULTS")
    try:
        study = export_study(results, out, per_image=per_image, max_trials=max_trials, seed=seed, controls=controls,
                             attention_checks=attention_checks, max_images=max_images, post_url=post_url,
                             post_mode=post_mode, exposure_ms=exposure_ms, image_px=image_px, overwrite=overwrite)
    except (ValueError, FileExistsError) as err:
        raise typer.BadParameter(str(err)) from err
    counts = study.counts()
    typer.echo(f"wrote {study.out_dir}/index.html: {counts['adversarial']} adversarial images, {counts['control']} "
               f"controls, {counts['attention']} attention checks; {len(study.plan.participants)} participants "
               f"(open index.html?participant=0 .. {len(study.plan.participants) - 1})")


def analyze(
    answers: List[Path] = typer.Argument(..., help="Answer files (CSV or JSON) downloaded from the study page."),
    out: Path = typer.Option(..., "-o", "--out", help="Folder for README.md, summary.json and the figure."),
    keep_inattentive: bool = typer.Option(False, "--keep-inattentive",
                                          help="Keep participants who failed an attention check."),
) -> None:
    """Share of answers choosing the true class (mean ± std over participants) beside the paper's 99.29 ± 1.96%."""
    from meshadv.study.analysis import write_analysis

    missing = [str(p) for p in answers if not p.is_file()]
    if missing:
        raise typer.BadParameter(f"missing answer files: {', '.join(missing)}", param_hint="ANSWERS")
    try:
        summary = write_analysis(answers, out, drop_failed_attention=not keep_inattentive)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="ANSWERS") from err
    g = summary.adversarial[0]
    typer.echo(f"true class chosen: {100 * g.mean:.2f} ± {100 * g.std:.2f}% ({g.answers} answers, "
               f"{g.participants} participants; {summary.dropped_attention} dropped for attention checks; "
               f"paper: 99.29 ± 1.96%); wrote {out}/README.md")


def register(app: typer.Typer) -> None:
    """Add the ``study`` command group (``export``, ``analyze``) to ``app``."""
    group = typer.Typer(help="The human perceptual study: a static 2AFC web page and the analysis of its answers.",
                        no_args_is_help=True)
    group.command("export")(export)
    group.command("analyze")(analyze)
    app.add_typer(group, name="study")
