"""``python -m uwval`` runs the CLI."""

from uwval.cli import main

main()
