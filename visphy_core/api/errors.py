"""The errors a plugin raises (`visphy_core.infra.errors`): `UserError` when the message alone
tells the user what to change (exit status 2, one line, no traceback), `ConfigError` for a bad
config value, `SceneDataError` for a bad file of one scene."""

from visphy_core.infra.errors import ConfigError, SceneDataError, UserError

__all__ = ["ConfigError", "SceneDataError", "UserError"]
