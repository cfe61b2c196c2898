"""Errors that are the user's input, not a bug: the CLI prints them as one line and exits 2.

Subclass `UserError` for any error whose message alone tells the user what to change (a bad
config value, a missing file they named, a tool they have to install). Everything else is a bug
and keeps its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input or a missing prerequisite: one line on stderr, exit status 2, no traceback."""

    exit_code = 2


class ConfigError(UserError, ValueError):
    """A config option, key or value that is not valid."""
