"""What every makeway command shares: one-line errors, JSON lines, the consoles."""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from typing import Any, TypeVar

import typer
from rich.console import Console

from makeway.errors import MakewayError
from makeway.jsonable import to_jsonable

console = Console()
err_console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


def friendly_errors(func: F) -> F:
    """Turn makeway's own errors (and ValueErrors from bad options) into one red line, exit code 2."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (MakewayError, ValueError) as exc:
            err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
            raise typer.Exit(code=2) from None

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
