"""The one exception tree of cam2sim.

Every error cam2sim raises on purpose derives from :class:`Cam2SimError`. Each concern has a
subclass that also inherits the matching builtin, so callers may catch either. Messages say what
was found, what was expected and what to do next.
"""

from __future__ import annotations

__all__ = [
    "BackendUnavailableError",
    "Cam2SimError",
    "ConfigError",
    "RecordingError",
    "SchemaVersionError",
    "StageError",
    "WorkspaceError",
]


class Cam2SimError(Exception):
    """Root of every error cam2sim raises on purpose."""


class ConfigError(Cam2SimError, ValueError):
    """A configuration value is missing, malformed or inconsistent."""


class WorkspaceError(Cam2SimError, OSError):
    """The workspace folder or one of its artifacts is missing, unreadable or malformed."""


class SchemaVersionError(Cam2SimError, ValueError):
    """An artifact was written by a newer (or unknown) schema version."""


class RecordingError(Cam2SimError, ValueError):
    """A recording (bag, image folder, pose table) cannot be read as configured."""


class StageError(Cam2SimError, RuntimeError):
    """A stage cannot run (missing upstream artifact, inconsistent inputs)."""


class BackendUnavailableError(Cam2SimError, ImportError):
    """An optional backend's dependency is not installed."""
