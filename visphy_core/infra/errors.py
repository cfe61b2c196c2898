"""Errors that are the user's input or a scene's data, not a bug. A `UserError` is printed by
the CLI as one line (exit status 2); a `SceneDataError` makes one scene a ``data_error`` row.

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


class SceneDataError(ValueError):
    """A bad input of one scene (a malformed or missing file): the scene's row is ``data_error``,
    the run goes on. The message is one line naming the file."""


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines included) as one space: an error message
    fit for a table cell or a log line."""
    return " ".join(str(text).split())
