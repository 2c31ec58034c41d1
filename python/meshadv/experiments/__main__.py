"""``python -m meshadv.experiments sweep|report ...``: the sweep and report commands without the full CLI."""

from __future__ import annotations

import typer

from meshadv.commands import report, sweep

app = typer.Typer(help="MeshAdv experiment sweeps and reports.", no_args_is_help=True)
sweep.register(app)
report.register(app)

if __name__ == "__main__":
    app()
