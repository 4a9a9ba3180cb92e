"""Errors a user can cause; the CLI turns them into one line on stderr and an exit code."""

from __future__ import annotations


class Tron1Error(Exception):
    """A runtime failure the user can act on (exit code 1): bad file, mismatched contract."""

    exit_code = 1


class UsageError(Tron1Error):
    """A bad option value (exit code 2)."""

    exit_code = 2
