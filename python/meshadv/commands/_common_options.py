"""What every ``meshadv`` command shares: the ``--threads`` option and one-line errors for natural mistakes.

:func:`install` walks a typer application (its commands and command groups, recursively) and wraps each command
callback so that

- it gains ``--threads N`` (unless it already has a ``threads`` parameter), applied through
  :func:`meshadv.threads.apply_threads` before the command runs;
- the exceptions a user's mistake raises (a missing file, a bad value, an optional package not installed) end the
  command with one line, ``Error: <message>`` and exit status 1, instead of a traceback. Set ``MESHADV_DEBUG=1`` to
  get the traceback;
- SIGTERM (``kill``, a batch scheduler's stop) takes Ctrl-C's path (:func:`terminate_as_interrupt`): commands that
  keep their finished work on Ctrl-C (``sweep``, ``attack``, ``transfer controlled``) keep it on ``kill`` too, and an
  interrupt that no command handles ends with one line and exit status 130, the shell's code for it.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import os
import signal
import threading
from typing import Any, Callable, Dict, Iterator, Optional

import typer

__all__ = ["DEBUG_ENV_VAR", "INTERRUPTED_EXIT_CODE", "OPTIONAL_PACKAGES", "install", "interrupted_exit",
           "one_line_error", "terminate_as_interrupt", "wrap_command"]

#: Environment variable that turns the one-line errors back into tracebacks.
DEBUG_ENV_VAR = "MESHADV_DEBUG"
#: Top-level module of an optional dependency -> the pip install line that provides it.
OPTIONAL_PACKAGES: Dict[str, str] = {
    "mitsuba": "pip install 'meshadv[transfer]'  (Mitsuba 3, for `meshadv transfer`)",
    "drjit": "pip install 'meshadv[transfer]'  (Mitsuba 3, for `meshadv transfer`)",
    "ray": "pip install 'meshadv[cluster]'  (Ray, for `--backend ray`)",
    "cv2": "pip install opencv-python-headless",
    "selenium": "pip install selenium",
}
#: Exit status of a command stopped by Ctrl-C or SIGTERM (128 + SIGINT, as a shell reports it).
INTERRUPTED_EXIT_CODE = 130
_WRAPPED = "__meshadv_common_options__"
#: click's ClickException as typer uses it (typer >= 0.20 vendors click, older typer uses the click package).
_ClickException = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")
_THREADS_HELP = ("Threads for the renderer and torch (default: $MESHADV_THREADS, else the CPUs available); results "
                 "are reproducible for a given --seed and --threads.")


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """While the block runs (in the main thread), SIGTERM raises ``KeyboardInterrupt``, so a ``kill`` takes
    Ctrl-C's path; the previous handler is restored afterwards (elsewhere than the main thread it does nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupted_exit(message: str = "interrupted") -> typer.Exit:
    """How a command ends on Ctrl-C or SIGTERM: print ``message`` (what was kept, how to resume) on a line of its own
    to stderr and return the ``typer.Exit`` with :data:`INTERRUPTED_EXIT_CODE` for the caller to raise."""
    typer.echo(f"\n{message}", err=True)
    return typer.Exit(INTERRUPTED_EXIT_CODE)


def one_line_error(exc: BaseException) -> Optional[str]:
    """The one-line message for an exception a user's mistake raises, or ``None`` for anything else (a bug).

    Args:
        exc: the exception.

    Returns:
        The message (with the fix where one is known), or ``None``.
    """
    if isinstance(exc, ImportError) and not isinstance(exc, ModuleNotFoundError):
        return str(exc) if "pip install" in str(exc) else None  # our own "needs X: pip install X" errors
    if isinstance(exc, ModuleNotFoundError):
        module = (exc.name or "").split(".")[0]
        if not module or module == "meshadv":
            return None  # a broken installation or a bug, not a user's mistake
        hint = OPTIONAL_PACKAGES.get(module, f"pip install {module}  (or reinstall meshadv: pip install meshadv)")
        return f"this needs the package '{module}', which is not installed: {hint}"
    if isinstance(exc, (FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError)):
        if exc.filename is not None:
            return f"{exc.strerror or 'cannot open'}: {exc.filename}"
        return str(exc)
    if isinstance(exc, ValueError):
        return str(exc)
    return None


def wrap_command(func: Callable[..., Any]) -> Callable[..., Any]:
    """``func`` with ``--threads`` added (unless it has a ``threads`` parameter), one-line errors, and SIGTERM
    taken as Ctrl-C.

    Args:
        func: a typer command callback.

    Returns:
        The wrapped callback (``func`` itself when it is already wrapped).
    """
    if getattr(func, _WRAPPED, False):
        return func
    signature = inspect.signature(func, eval_str=True)
    adds_threads = "threads" not in signature.parameters

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if adds_threads:
            from meshadv.threads import apply_threads

            apply_threads(kwargs.pop("threads", None))
        try:
            with terminate_as_interrupt():
                return func(*args, **kwargs)
        except (_ClickException, typer.Exit, typer.Abort):
            raise
        except KeyboardInterrupt:
            raise interrupted_exit() from None
        except Exception as exc:
            message = one_line_error(exc)
            if message is None or os.environ.get(DEBUG_ENV_VAR):
                raise
            raise _ClickException(f"{message}  [{DEBUG_ENV_VAR}=1 shows the traceback]") from exc

    params = list(signature.parameters.values())
    annotations = {p.name: p.annotation for p in params if p.annotation is not inspect.Parameter.empty}
    if adds_threads:
        option = typer.Option(None, "--threads", min=1, help=_THREADS_HELP, show_default=False)
        params.append(inspect.Parameter("threads", inspect.Parameter.KEYWORD_ONLY, default=option,
                                        annotation=Optional[int]))
        annotations["threads"] = Optional[int]
    if signature.return_annotation is not inspect.Signature.empty:
        annotations["return"] = signature.return_annotation
    wrapper.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = annotations
    setattr(wrapper, _WRAPPED, True)
    return wrapper


def install(app: typer.Typer) -> None:
    """Wrap every command of ``app`` and of its command groups (recursively) with :func:`wrap_command`."""
    for info in app.registered_commands:
        if info.callback is not None:
            info.callback = wrap_command(info.callback)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            install(group.typer_instance)
