"""Errors a user can cause; the CLI turns them into one line on stderr and an exit code."""

from __future__ import annotations


class Tron1Error(Exception):
    """A runtime failure the user can act on (exit code 1): bad file, mismatched contract."""

    exit_code = 1


class UsageError(Tron1Error):
    """A bad option value (exit code 2)."""

    exit_code = 2


class Interrupted(Tron1Error):
    """Ctrl-C (or SIGTERM where a command maps it) stopped a command (exit code 130); the message
    says what the command kept."""

    exit_code = 130


def one_line(message: str) -> str:
    """``message`` as one line: its lines joined with '; ', blank ones dropped."""
    return "; ".join(x.strip() for x in str(message).splitlines() if x.strip())


def describe(e: BaseException) -> str:
    """An exception as one short line: its type and the first line of its message (the type
    alone when the message is empty)."""
    lines = [x.strip() for x in str(e).splitlines() if x.strip()]
    return f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__
