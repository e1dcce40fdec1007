"""The `aftershock` command line. Each command lives in its own module under `pipeline.commands`."""

from __future__ import annotations

import importlib
import logging
import sys
import warnings
from typing import Final

import typer

from aftershock.pipeline.errors import AftershockError, DamagedLogWarning

COMMAND_MODULES: Final[tuple[str, ...]] = (
    "info",
    "simulate",
    "run",
    "evaluate",
    "train",
    "cracks",
    "drift",
    "refine",
    "view",
)

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


def _register_commands() -> None:
    for name in COMMAND_MODULES:
        module_name = f"aftershock.pipeline.commands.{name}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:  # command not built yet in this checkout
                continue
            raise
        module.register(app)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    if issubclass(category, DamagedLogWarning | UserWarning):
        print(f"aftershock: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


def main(argv: list[str] | None = None) -> int:
    """Entry point: user mistakes become one line on stderr and exit code 2, Ctrl-C exit code 130."""
    logging.basicConfig(level=logging.WARNING, format="aftershock: %(levelname)s: %(message)s")
    warnings.showwarning = _show_warning
    _register_commands()
    try:
        result = app(args=argv, standalone_mode=False)
    except AftershockError as exc:
        print(f"aftershock: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("aftershock: interrupted", file=sys.stderr)
        return 130
    except typer.Exit as exc:
        return exc.exit_code
    except Exception as exc:  # click's usage errors
        import click

        if isinstance(exc, click.exceptions.Abort):
            print("aftershock: interrupted", file=sys.stderr)
            return 130
        if isinstance(exc, click.ClickException):
            exc.show()
            return exc.exit_code
        raise
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())
