"""Make a results database written with absolute paths portable: relative job folders, no machine's paths left.

A database the sweep writes now stores each job's folder relative to the database's own folder and its config's
path relative to it too (:class:`meshadv.experiments.ResultStore`). A database written with the absolute paths of
the machine that ran it is rewritten in place:

* ``jobs.out_dir`` ``<anything>/jobs/<id[:2]>/<id>`` becomes ``jobs/<id[:2]>/<id>`` (next to the database, where the
  commands that need a job's artefacts put them back: rebuilt from its stored perturbation, else regenerated);
* ``meta.config_path`` becomes the path of ``--config`` relative to the database's folder;
* absolute paths inside ``--checkout`` (the run machine's checkout, e.g. ``/work/main``) in the other meta values
  (the recorded command line) become paths relative to the checkout;
* the ``perturbations`` table is created (empty: the records predate it).

Nothing else changes; the file is closed without a write-ahead log, as a committed database must be.

    python3 scripts/portable_results_db.py docs/results/paper_small/results.db --config configs/paper_small.toml \\
        --checkout /work/main --checkout /work/sweep
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sqlite3
from pathlib import Path
from typing import List


def _relative_job_dir(out_dir: str, job_id: str) -> str:
    """``jobs/<id[:2]>/<id>`` for a stored absolute job folder of that job, else ``out_dir`` unchanged."""
    tail = f"jobs/{job_id[:2]}/{job_id}"
    return tail if os.path.isabs(out_dir) and out_dir.rstrip("/").endswith(tail) else out_dir


def make_portable(db: Path, config: Path, checkouts: List[str]) -> dict:
    """Rewrite ``db`` in place (see the module docstring); return what changed (counts)."""
    from meshadv.experiments.store import _SCHEMA

    conn = sqlite3.connect(db, isolation_level=None)
    try:
        changed = {"out_dir": 0, "meta": 0}
        conn.execute("BEGIN IMMEDIATE")
        for job_id, out_dir in conn.execute("SELECT job_id, out_dir FROM jobs WHERE out_dir IS NOT NULL").fetchall():
            new = _relative_job_dir(out_dir, job_id)
            if new != out_dir:
                conn.execute("UPDATE jobs SET out_dir = ? WHERE job_id = ?", (new, job_id))
                changed["out_dir"] += 1
        config_path = os.path.relpath(config.resolve(), db.resolve().parent)
        # meta values are JSON (ResultStore.set_meta)
        conn.execute("UPDATE meta SET value = ? WHERE key = 'config_path'", (json.dumps(config_path),))
        changed["meta"] += 1
        pattern = re.compile("|".join(re.escape(c.rstrip("/") + "/") for c in checkouts))
        for key, value in conn.execute("SELECT key, value FROM meta WHERE key != 'config_path'").fetchall():
            new = pattern.sub("", value) if checkouts else value
            if new != value:
                conn.execute("UPDATE meta SET value = ? WHERE key = ?", (new, key))
                changed["meta"] += 1
        conn.execute("COMMIT")
        conn.executescript(_SCHEMA)  # the perturbations table (IF NOT EXISTS: the others stay as they are)
    finally:
        conn.close()
    for suffix in ("-wal", "-shm"):
        if Path(f"{db}{suffix}").exists():
            raise RuntimeError(f"{db}{suffix} is left behind; open the database once with sqlite3 to checkpoint it")
    return changed


def main() -> None:
    """The command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("db", type=Path, help="the results.db to rewrite in place")
    parser.add_argument("--config", type=Path, required=True, help="the sweep file the database ran")
    parser.add_argument("--checkout", action="append", default=[],
                        help="a checkout root of the run machine whose absolute paths become relative (repeatable)")
    args = parser.parse_args()
    print(make_portable(args.db, args.config, args.checkout))


if __name__ == "__main__":
    main()
