"""Exceptions that the CLI turns into one-line messages and exit codes.

* :class:`CaseError` - bad input (exit code 2): names the key and the reason.
* :class:`RunError` - a run that failed (blow-up, solver failure; exit code 3).
"""

from __future__ import annotations


class CfddemError(Exception):
    exit_code = 1


class CaseError(CfddemError):
    """Bad input: a one-line message naming the key and the reason."""

    exit_code = 2

    def __init__(self, key: str | None, reason: str):
        self.key = key
        self.reason = reason
        super().__init__(f"{key}: {reason}" if key else reason)


class RunError(CfddemError):
    """A run that failed: blow-up, solver failure.  The message says where and why."""

    exit_code = 3
