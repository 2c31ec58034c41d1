"""The ``meshadv`` command line (typer).

Each subcommand lives in its own module under :mod:`meshadv.commands` and is listed in :data:`SUBCOMMANDS` as
``name -> "module:function"``. A module may instead define ``register(app: typer.Typer) -> None`` (used when it
adds a command group); the ``function`` part is then ignored. Entries whose module is not present in this build are
skipped, so a subcommand can be listed before its module lands. Modules import heavy dependencies inside the
command functions, keeping ``meshadv --help`` fast.

Example:
    $ meshadv demo -o out/demo
    $ meshadv attack pascal3d/chair/01.ply --victim efficientnet_lite0 --target bicycle --perturbation shape -o out/a
    $ meshadv render builtin:sphere --views 4 -o out/r
"""

from __future__ import annotations

import importlib
from typing import Dict, List, Optional

import typer

from meshadv.commands._common_options import install as install_common_options
from meshadv.allocator import tune_allocator
from meshadv.threads import prepare_environment

__all__ = ["app", "main", "SUBCOMMANDS", "build_app"]

#: Subcommand name -> ``"module:function"`` (module relative to ``meshadv.commands``).
SUBCOMMANDS: Dict[str, str] = {
    "attack": "attack:attack",
    "render": "render:render",
    "demo": "demo:demo",
    "attack-scene": "attack_scene:attack_scene",
    "sweep": "sweep:sweep",
    "report": "report:report",
    "regenerate": "regenerate:regenerate",
    "transfer": "transfer:transfer",
    "rendering-set": "rendering_set:build",
    "study": "study:register",
}


def build_app(subcommands: Optional[Dict[str, str]] = None) -> typer.Typer:
    """Build the typer application from ``subcommands`` (default :data:`SUBCOMMANDS`).

    Args:
        subcommands: mapping name -> ``"module:function"``.

    Returns:
        The application.
    """
    application = typer.Typer(
        name="meshadv",
        help="Differentiable mesh rendering and MeshAdv adversarial meshes (Xiao et al., CVPR 2019).",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )
    for name, target in (subcommands or SUBCOMMANDS).items():
        module_name, _, func_name = target.partition(":")
        full = f"meshadv.commands.{module_name}"
        try:
            module = importlib.import_module(full)
        except ModuleNotFoundError as exc:
            if exc.name == full:
                continue  # listed but not part of this build yet
            raise
        if hasattr(module, "register"):
            module.register(application)
        else:
            application.command(name)(getattr(module, func_name))
    application.callback()(_root)
    install_common_options(application)  # --threads and one-line errors on every command
    return application


def _version(value: bool) -> None:
    if value:
        from meshadv import __version__

        typer.echo(f"meshadv {__version__}")
        raise typer.Exit()


def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """Differentiable mesh rendering and MeshAdv adversarial meshes (Xiao et al., CVPR 2019)."""


app = build_app()


def main(argv: Optional[List[str]] = None) -> None:
    """Entry point of the ``meshadv`` console script.

    Args:
        argv: arguments (default ``sys.argv[1:]``).
    """
    prepare_environment()  # OpenMP wait policy and pool sizes: must precede torch's import (meshadv.threads)
    tune_allocator()  # keep large freed blocks instead of faulting them in every step (meshadv.allocator)
    app(args=argv, prog_name="meshadv")


if __name__ == "__main__":
    main()
