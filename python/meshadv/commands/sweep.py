"""``meshadv sweep CONFIG``: expand a sweep file into attack jobs and run them resumably.

Results go to the SQLite database named by the config (``<output>/results.db`` by default). Run the same command
again after a kill to resume: finished jobs are skipped, interrupted ones re-run, failed ones retried up to
``max_attempts``. Ctrl-C and SIGTERM (``kill``, a batch scheduler's stop) end a run the same way: the workers are
stopped, running jobs go back to pending and the database is closed cleanly. To end without losing the running jobs'
work, ``--stop-starting-after DURATION`` or SIGUSR1 to the driver stop starting jobs: the running ones finish and are
recorded, then the command exits (a batch slot's time limit; e.g. Slurm's ``--signal=USR1@900``). When the output
folder is scratch space that may vanish with its machine, ``--snapshot PATH`` keeps a resumable copy of the database
somewhere durable, rewritten atomically as results arrive and once more at the end.

Progress: one bar counts the jobs (successes, failures, ETA), a second one the attack steps out of the most the
planned jobs can run, moving at every step of every running job with the local and serial backends (the workers
report their steps to this process) and per finished job with Ray.

With ``[attack.retry]`` in the config, every main-setting attack that fails is run again with a larger budget
(:mod:`meshadv.experiments.retries`): the retries of earlier runs' failures come right after the main setting's
jobs, and the failures of this run are retried before the command ends (``--only retry`` runs the retries alone).
With several stages (``[[attack.retry]]``), a retry that fails is retried by the next stage in the same way.
"""

from __future__ import annotations

import contextlib
import dataclasses
import shlex
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Iterator, List, Optional

import typer

if TYPE_CHECKING:
    from meshadv.experiments import ResultStore

__all__ = ["DatabaseSnapshots", "StopStarting", "register", "sweep"]


class StopStarting:
    """When a sweep stops starting jobs (``run_sweep``'s ``stop_starting``): once ``after_s`` seconds have passed
    since it was made, or once SIGUSR1 arrives while :meth:`on_sigusr1` is active. ``reason`` says which."""

    def __init__(self, after_s: Optional[float] = None) -> None:
        self.deadline = None if after_s is None else time.monotonic() + after_s
        self.reason: Optional[str] = None

    def __call__(self) -> bool:
        """Whether to stop starting jobs."""
        if self.reason is None and self.deadline is not None and time.monotonic() >= self.deadline:
            self.reason = "--stop-starting-after reached"
        return self.reason is not None

    @contextlib.contextmanager
    def on_sigusr1(self) -> Iterator[None]:
        """While the block runs (in the main thread, where the platform has SIGUSR1), SIGUSR1 stops the starting of
        jobs; the previous handler is restored afterwards."""
        if not hasattr(signal, "SIGUSR1") or threading.current_thread() is not threading.main_thread():
            yield
            return

        def _stop(signum: int, frame: Any) -> None:
            self.reason = self.reason or "SIGUSR1 received"

        previous = signal.signal(signal.SIGUSR1, _stop)
        try:
            yield
        finally:
            signal.signal(signal.SIGUSR1, previous)


class DatabaseSnapshots:
    """Resumable copies of a sweep's database at ``path`` (``meshadv sweep --snapshot``): after a recorded outcome
    once ``every_s`` seconds have passed since the last copy, and whenever :meth:`write` is called (the run's end).

    Args:
        store: the sweep's results database.
        path: where the copy goes (:meth:`meshadv.experiments.ResultStore.snapshot`).
        every_s: the least time between two copies made after outcomes, >= 0.
    """

    def __init__(self, store: "ResultStore", path: Path, every_s: float) -> None:
        self.store = store
        self.path = Path(path)
        self.every_s = float(every_s)
        self.last: Optional[float] = None

    def after_outcome(self, job_id: str, ok: bool) -> None:
        """``run_sweep``'s ``on_outcome``: copy the database when the last copy is old enough."""
        if self.last is None or time.monotonic() - self.last >= self.every_s:
            self.write()

    def write(self) -> None:
        """Copy the database now."""
        self.store.snapshot(self.path)
        self.last = time.monotonic()


def sweep(
    config: Path = typer.Argument(..., help="Sweep file (.toml, .yaml or .yml)."),
    backend: str = typer.Option("local", help="local (process pool, default), ray or serial."),
    address: Optional[str] = typer.Option(None, help="Ray cluster address; without it Ray starts locally."),
    ray_artifacts: str = typer.Option("return", help="Ray: 'return' (artefacts come back to this machine through "
                                      "Ray: no shared file system needed), an fsspec URL to upload them to "
                                      "(s3://bucket/run), or 'shared' (every node writes the output folder)."),
    ray_resource: Optional[List[str]] = typer.Option(None, help="Ray: a custom resource NAME=AMOUNT each job needs, "
                                                     "to pin jobs to nodes started with it (repeatable)."),
    workers: Optional[int] = typer.Option(None, help="Parallel jobs (0 = every core; default: the config's "
                                          "runner.workers)."),
    db: Optional[Path] = typer.Option(None, help="Results database (default: from the config)."),
    output: Optional[Path] = typer.Option(None, help="Artefact folder (default: from the config)."),
    max_attempts: Optional[int] = typer.Option(None, help="Attempts per job (default: the config's)."),
    timeout: Optional[float] = typer.Option(None, help="Per-job timeout in seconds, local backend (0 = none)."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Only expand and check the jobs (victim names, mesh "
                                 "files, target classes) and print how many there are (with a database: the "
                                 "retries due and how many jobs are finished)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the progress bars (jobs; attack "
                                  "steps, per step with the local and serial backends, per job with Ray)."),
    only: Optional[List[str]] = typer.Option(None, help="Run only these parts of the sweep (repeatable): 'main', "
                                             "a protocol's name (e.g. 'paper') or 'multiview' (Table 2). The "
                                             "database keeps every part's finished jobs; the other parts wait "
                                             "for a run without --only."),
    where: Optional[List[str]] = typer.Option(None, help="Run only the jobs whose spec has KEY=VALUE (repeatable; "
                                              "all must hold): e.g. --where source_class=sofa --where "
                                              "target=bicycle, config_index=0, perturbation=shape, mesh.class="
                                              "chair. The other jobs wait for a run without --where."),
    stop_starting_after: Optional[str] = typer.Option(
        None, "--stop-starting-after", help="Start no job after this long (90m, 2h, 1h30m; a bare number is "
        "seconds): the running jobs finish and are recorded, the rest wait for the next run. SIGUSR1 to this "
        "process does the same at once (e.g. Slurm's --signal=USR1@900)."),
    snapshot: Optional[Path] = typer.Option(None, help="Keep a resumable copy of the results database at this path "
                                            "(e.g. on durable storage while the output folder is scratch space), "
                                            "rewritten atomically after results arrive and at the end."),
    snapshot_every: str = typer.Option("1m", "--snapshot-every", help="With --snapshot: the least time between two "
                                       "copies made as results arrive (90s, 10m; 0: after every result)."),
) -> None:
    """Run (or resume) the attack sweep described by CONFIG."""
    from meshadv.commands._common import parse_duration
    from meshadv.commands._common_options import interrupted_exit
    from meshadv.commands._job_index import warn_damaged_results, write_job_index
    from meshadv.experiments import ResultStore, make_backend, run_sweep
    from meshadv.experiments.config import (
        DEFAULT_JOB,
        expand_jobs,
        load_config,
        parse_where,
        select_parts,
        select_where,
    )
    from meshadv.experiments.jobs import planned_steps
    from meshadv.experiments.retries import RETRY_PART, place_retries, retry_jobs
    from meshadv.experiments.report import environment_versions
    from meshadv.experiments.store import check_snapshot_target
    from meshadv.util.paths import relative_path

    try:
        cfg = load_config(config)
    except (ValueError, FileNotFoundError) as err:
        raise typer.BadParameter(str(err), param_hint="CONFIG") from err
    expanded = expand_jobs(cfg)
    retry_parts = [RETRY_PART] if cfg.attack["retry"] else []

    try:
        conditions = parse_where(where or [])
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--where") from err

    def selected(specs: List[Dict[str, Any]]) -> List[Dict[str, Any]]:
        """The jobs of ``specs`` that --only and --where pick (all of them without either); a part or a key the
        sweep lacks is a usage error naming its option."""
        try:
            parts = select_parts(specs, only, also_known=retry_parts) if only else specs
        except ValueError as err:
            raise typer.BadParameter(str(err), param_hint="--only") from err
        try:
            return select_where(parts, conditions)
        except ValueError as err:
            raise typer.BadParameter(str(err), param_hint="--where") from err

    jobs = selected(expanded)
    try:
        after_s = None if stop_starting_after is None else parse_duration(stop_starting_after,
                                                                           "--stop-starting-after")
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--stop-starting-after") from err
    try:
        snapshot_every_s = parse_duration(snapshot_every, "--snapshot-every")
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--snapshot-every") from err
    db_path = db or cfg.db
    out_root = output or cfg.output
    if snapshot is not None:  # refused now, not after the first result
        try:
            check_snapshot_target(db_path, snapshot)
        except ValueError as err:
            raise typer.BadParameter(str(err), param_hint="--snapshot") from err
    if dry_run:
        from meshadv.commands._sweep_check import check_jobs

        from meshadv.experiments.spec import job_id

        finished = ""
        if Path(db_path).exists():  # the retries due so far, and how many jobs are finished already
            try:
                with ResultStore(db_path, read_only=True) as store:
                    rows = store.rows()
            except ValueError as err:
                typer.echo(f"meshadv sweep: error: {err}", err=True)
                raise typer.Exit(1) from None
            if retry_parts:
                jobs = selected(place_retries(expanded, retry_jobs(cfg.attack["retry"], rows)))
            done = {r.job_id for r in rows if r.state == "done"}
            finished = f", {sum(job_id(j) in done for j in jobs)} finished"
        kinds = {k: sum(j["kind"] == k for j in jobs) for k in ("single", "multiview")}
        typer.echo(f"{len(jobs)} jobs ({kinds['single']} single-view, {kinds['multiview']} multi-view){finished}; "
                   f"database {db_path}; artefacts {out_root}")
        # the names mean something to the built-in attack job; a custom [runner] job reads its specs its own way
        problems = check_jobs(jobs) if cfg.runner["job"] == DEFAULT_JOB else []
        for problem in problems:
            typer.echo(f"error: {problem}", err=True)
        if problems:
            raise typer.Exit(1)
        return
    runner = cfg.runner
    n_workers = int(runner["workers"]) if workers is None else workers
    attempts = int(runner["max_attempts"]) if max_attempts is None else max_attempts
    resources: Dict[str, float] = {}
    for item in ray_resource or []:
        name, sep, amount = item.partition("=")
        try:
            resources[name] = float(amount) if sep else 1.0
        except ValueError as err:
            raise typer.BadParameter(f"expected NAME=AMOUNT, got {item!r}", param_hint="--ray-resource") from err
    try:
        be = make_backend(backend, workers=n_workers, threads_per_job=int(runner["threads_per_job"]),
                          timeout=float(runner["timeout"] if timeout is None else timeout), address=address,
                          max_jobs_per_worker=int(runner["max_jobs_per_worker"]), artifacts=ray_artifacts,
                          resources=resources or None)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--backend / --address") from err
    try:
        store = ResultStore(db_path)
    except ValueError as err:  # an empty, truncated or WAL-less database: one line saying what to do
        typer.echo(f"meshadv sweep: error: {err}", err=True)
        raise typer.Exit(1) from None
    with store:
        store.set_meta("name", cfg.name)
        # relative to the database's folder, as its job folders: a copied run folder keeps pointing at its config
        store.set_meta("config_path", relative_path(config, Path(db_path).resolve().parent))
        store.set_meta("config_text", cfg.text)
        store.set_meta("command", "meshadv sweep " + " ".join(shlex.quote(a) for a in sys.argv[2:]))
        store.set_meta("sweep_versions", environment_versions())
        stop = StopStarting(after_s)
        snapshots = None if snapshot is None else DatabaseSnapshots(store, snapshot, snapshot_every_s)

        def with_due_retries() -> List[Dict[str, Any]]:
            """The sweep's jobs with the retries of the main attacks that have failed so far."""
            due = retry_jobs(cfg.attack["retry"], store.rows()) if retry_parts else []
            return selected(place_retries(expanded, due))

        try:
            with stop.on_sigusr1():
                jobs, ran = with_due_retries(), 0
                while True:  # again while this run's failures added retries
                    summary = run_sweep(store, jobs, runner["job"], out_root=out_root, backend=be,
                                        max_attempts=attempts, progress=progress,
                                        planned_steps=planned_steps if runner["job"] == DEFAULT_JOB else None,
                                        stop_starting=stop,
                                        on_outcome=None if snapshots is None else snapshots.after_outcome)
                    ran += summary.ran
                    if summary.not_started:
                        break
                    more = with_due_retries()
                    if len(more) == len(jobs):
                        break
                    jobs = more
                summary = dataclasses.replace(summary, ran=ran)
            write_job_index(store, out_root, out_root)  # index.csv / index.md: job id -> folder and settings
        except KeyboardInterrupt:
            be.close()
            requeued = store.requeue_running()
            if snapshots is not None:
                snapshots.write()
            counts = store.counts()
            raise interrupted_exit(f"interrupted: {counts.get('done', 0)} finished job(s) are kept in {db_path}; "
                                   f"{requeued} running job(s) were put back to pending; run the same command again "
                                   "to resume") from None
        finally:
            be.close()
        if snapshots is not None:
            snapshots.write()
    typer.echo(f"{summary.done}/{summary.total} done ({summary.successes} successful), {summary.failed} failed; "
               f"ran {summary.ran}, skipped {summary.skipped} finished, re-queued {summary.requeued} interrupted; "
               f"results in {db_path}")
    if summary.not_started:
        typer.echo(f"stopped starting jobs ({stop.reason}): {summary.not_started} job(s) wait for the next run; run "
                   "the same command again to continue")
    with ResultStore(db_path) as store:
        warn_damaged_results(store, db_path)
    if summary.failed:
        typer.echo(f"{summary.failed} job(s) failed: see the 'error' column of {db_path}", err=True)
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add the ``sweep`` command to ``app``."""
    app.command("sweep")(sweep)
