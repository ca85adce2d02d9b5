"""``python -m makeway`` runs the command line."""

from makeway.cli.main import app

app()
