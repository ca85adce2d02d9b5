"""What every makeway command shares: one-line errors, JSON lines, the consoles."""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from typing import Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape

from makeway.errors import MakewayError
from makeway.jsonable import to_jsonable

console = Console()
err_console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


#: exit codes of every makeway command (docs/cli_contract.md)
EXIT_OK = 0
EXIT_NEGATIVE = 1  # the command ran and its answer is "no" (e.g. ``v2x verify`` rejected a message)
EXIT_BAD_INPUT = 2  # bad input, bad output path or bad usage: one ``error:`` line names the file
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT); outputs are written atomically, so none is half-written


def _one_line(text: str) -> str:
    return " ".join(text.split())


def error_line(exc: BaseException) -> str:
    """The one line a command prints for an error it refuses: ``FILE: problem`` for makeway's own
    errors, the file and the system's words for an operating-system error (``OSError``), the message
    for a bad option value (``ValueError``)."""
    if isinstance(exc, OSError) and not isinstance(exc, MakewayError):
        where = exc.filename if exc.filename is not None else ""
        what = exc.strerror or type(exc).__name__
        return _one_line(f"{where}: {what}" if where != "" else f"{what}")
    return _one_line(str(exc))


def friendly_errors(func: F) -> F:
    """The command-line contract (docs/cli_contract.md) for one command: makeway's own errors, bad
    option values (``ValueError``) and operating-system errors on a file (``OSError``: a full disk, a
    folder without write permission) end in one red ``error:`` line on stderr and exit code 2;
    Ctrl-C ends in one line and exit code 130. Any other exception is a bug and keeps its traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (MakewayError, ValueError, OSError) as exc:
            err_console.print(
                f"[bold red]error:[/] {escape(error_line(exc))}", highlight=False, soft_wrap=True
            )
            raise typer.Exit(code=EXIT_BAD_INPUT) from None
        except KeyboardInterrupt:
            err_console.print("interrupted: no output was left half-written", highlight=False)
            raise typer.Exit(code=EXIT_INTERRUPTED) from None

    wrapper.__makeway_contract__ = True  # type: ignore[attr-defined]  # checked by tests/test_cli_contract.py
    return wrapper  # type: ignore[return-value]


def print_json_line(obj: Any) -> None:
    """One strict-JSON object on one line of stdout (for machines; printed last): NaN and infinities
    become ``null``, numpy scalars plain numbers (:func:`makeway.jsonable.to_jsonable`, unrounded)."""
    sys.stdout.write(
        json.dumps(to_jsonable(obj, digits=None), separators=(", ", ": "), allow_nan=False) + "\n"
    )
    sys.stdout.flush()


def new_app(name: str, help_text: str) -> typer.Typer:
    """A typer app with makeway's settings."""
    return typer.Typer(
        name=name,
        help=help_text,
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
        rich_markup_mode=None,  # plain help: square brackets stay text, paragraphs rewrap to the terminal
        context_settings={"max_content_width": 120},
    )
