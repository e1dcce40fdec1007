"""The `aftershock` command line: each command is a function in its own module under `pipeline.commands`,
wired here one line each; the work itself is in the library (`pipeline.mission`, `pipeline.batch`, ...)."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import warnings
from typing import TYPE_CHECKING, Final

import typer

from aftershock.pipeline.commands import (
    batch,
    cracks,
    drift,
    evaluate,
    info,
    refine,
    report,
    run,
    simulate,
    train,
    view,
)
from aftershock.pipeline.errors import AftershockError, DamagedLogWarning
from aftershock.pipeline.text import SafeFormatter, safe

if TYPE_CHECKING:
    from typer._click.core import Context  # what typer hands an option's methods: its own copy of click's

EXIT_SIGINT: Final = 130  # 128 + the signal's number, as shells report a process a signal ended
EXIT_SIGTERM: Final = 143

app = typer.Typer(
    name="aftershock",
    help="Labelled, reviewable 3D pictures of disaster sites from robot LiDAR logs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        print(f"aftershock {version('aftershock')}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """Labelled, reviewable 3D pictures of disaster sites from robot LiDAR logs."""


app.command()(info.info)
app.command()(simulate.simulate)
app.command()(run.run)
app.command("eval")(evaluate.evaluate)
app.command()(train.train)
app.command()(cracks.cracks)
app.command()(drift.drift)
app.command()(refine.refine)
app.command()(view.view)
app.command()(batch.batch)
app.command()(report.report)


def _untag_flags() -> None:
    """No `<bool>` type tag after on/off flags (--help included) in `--help`: typer shows every option's type,
    and for a flag that reads as a value to give. Other options keep theirs (<path>, <int> ...)."""
    from typer.core import TyperOption

    shown = TyperOption.display_type_rich
    if getattr(shown, "untagged", False):
        return

    def display_type_rich(self: TyperOption, ctx: Context) -> str | None:
        return None if self.is_flag else shown(self, ctx)

    display_type_rich.untagged = True  # type: ignore[attr-defined]
    TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]


_untag_flags()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    if issubclass(category, DamagedLogWarning | UserWarning):
        print(f"aftershock: warning: {safe(message)}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


class _Terminated:
    """Set when SIGTERM arrived: the run stops as after Ctrl-C, and the exit code says which signal it was."""

    seen: bool = False
    interrupted: bool = False  # Ctrl-C or SIGTERM arrived


def _terminate(signum: int, _frame: object) -> None:
    # `docker stop`, systemd and `timeout` send SIGTERM: stop like Ctrl-C, so every output is finished.
    _Terminated.seen = True
    _Terminated.interrupted = True
    raise KeyboardInterrupt


def _interrupt(signum: int, _frame: object) -> None:
    # Ctrl-C, remembered: a KeyboardInterrupt raised inside a C extension's import comes out as another error
    # (open3d's "ImportError: initialization failed"), which must still read as the interruption it is
    _Terminated.interrupted = True
    raise KeyboardInterrupt


def _interrupted_code() -> int:
    return EXIT_SIGTERM if _Terminated.seen else EXIT_SIGINT


def main(argv: list[str] | None = None) -> int:
    """Entry point: user mistakes become one line on stderr and exit code 2 (usage errors: typer's usual
    message, also 2), Ctrl-C exit code 130, SIGTERM the same clean stop with 143."""
    if not sys.stderr.isatty():  # no colour codes in logs and files: Rerun's and rich's loggers honour NO_COLOR
        os.environ.setdefault("NO_COLOR", "1")
    # Rerun's Rust side logs its own connection and flush errors on stderr; aftershock reports them in one line
    os.environ.setdefault("RUST_LOG", "off")
    logging.basicConfig(level=logging.WARNING, format="aftershock: %(levelname)s: %(message)s")
    for handler in logging.getLogger().handlers:
        handler.setFormatter(SafeFormatter("aftershock: %(levelname)s: %(message)s"))
    warnings.showwarning = _show_warning
    _Terminated.seen = _Terminated.interrupted = False
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        previous = signal.signal(signal.SIGTERM, _terminate)
        previous_int = signal.signal(signal.SIGINT, _interrupt)
    try:
        code = _interrupted(argv)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)
    return _interrupted_code() if code == EXIT_SIGINT else code


def _interrupted(argv: list[str] | None) -> int:
    """`_dispatch`, where an error that an interruption caused (not the user's input) ends as the interruption."""
    try:
        code = _dispatch(argv)
    except Exception:
        if not _Terminated.interrupted:
            raise
        print("aftershock: interrupted", file=sys.stderr)
        return EXIT_SIGINT
    return EXIT_SIGINT if _Terminated.interrupted and code not in (0, EXIT_SIGINT) else code


def _dispatch(argv: list[str] | None) -> int:
    try:
        result = app(args=argv, standalone_mode=False)
    except AftershockError as exc:
        print(f"aftershock: error: {exc}", file=sys.stderr)
        if getattr(exc, "process_stuck", False):  # a wedged writer thread would keep the process from ending
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(2)
        return 2
    except KeyboardInterrupt:
        print("aftershock: interrupted", file=sys.stderr)
        return EXIT_SIGINT
    except OSError as exc:  # a path the system refuses (a name over 255 bytes, no permission) wherever it entered
        where = next((f for f in (exc.filename, exc.filename2) if f is not None), None)
        what = exc.strerror or type(exc).__name__
        print(f"aftershock: error: {safe(f'{where}: {what}' if where is not None else what)}", file=sys.stderr)
        return 2
    except typer.Exit as exc:
        if isinstance(exc.__cause__, KeyboardInterrupt):  # typer turns a Ctrl-C it meets into Exit(130), silently
            print("aftershock: interrupted", file=sys.stderr)
            return EXIT_SIGINT
        return exc.exit_code
    except typer.Abort:
        print("aftershock: interrupted", file=sys.stderr)
        return EXIT_SIGINT
    except typer.TyperException as exc:  # usage errors; typer raises its bundled click's, not click's own
        show = getattr(exc, "show", None)
        if show is not None:
            show()  # coloured only when stderr is a terminal
        else:
            print(f"aftershock: error: {exc.format_message()}", file=sys.stderr)
        return exc.exit_code
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())
