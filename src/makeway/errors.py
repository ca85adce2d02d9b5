"""Errors a user can act on.

Every problem with an input file (video, detection file, model, config) is raised as
:class:`InputError`, which names the file and says what is wrong with it in one sentence. The CLI
turns it into one red line on stderr and a non-zero exit code.
"""

from __future__ import annotations

from pathlib import Path


class MakewayError(Exception):
    """Base class for errors makeway raises on purpose."""


class InputError(MakewayError):
    """A named input is missing, unreadable or malformed.

    Args:
        path: the file (or folder) at fault.
        problem: what is wrong, phrased so the user knows what to fix (line breaks in it, from a
            library's message, become spaces).
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        # one line, whatever a library's message held (the CLI prints it as one ``error:`` line)
        self.problem = " ".join(part.strip() for part in problem.splitlines() if part.strip())
        shown = str(self.path)
        if any(c in shown for c in "\n\r\x00"):  # a name with line breaks: quoted, still one line
            shown = repr(shown)
        super().__init__(f"{shown}: {self.problem}")
