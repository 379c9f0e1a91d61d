"""The console's usage error: one line with the command's usage, exit status 2."""

from __future__ import annotations


class UsageError(Exception):
    """A bad command line: the CLI prints it with the subcommand's usage and exits 2."""
