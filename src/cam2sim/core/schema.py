"""Schema-versioned JSON artifacts, validated with pydantic on load.

Every JSON artifact cam2sim writes is a subclass of :class:`Artifact`. It carries
``schema_version``; loading rejects a newer version with a message naming both versions, and a
malformed file with a message naming the file and the offending element.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import ClassVar, Final, Self

import pydantic

from cam2sim.core.errors import SchemaVersionError, WorkspaceError
from cam2sim.core.files import read_json, write_text_atomic

__all__ = ["Artifact", "format_validation_error"]


MAX_LISTED: Final = 12
"""Distinct problems a validation message lists before it counts the rest."""


def format_validation_error(err: pydantic.ValidationError, *, source: str) -> str:
    """Return a one-paragraph message listing every invalid element of ``source``.

    Problems that differ only in list indices are one entry, with how often they occur (a
    prepared scene of 365 frames written by another cam2sim version has the same unknown field
    in every frame: one line, not 365); past :data:`MAX_LISTED` entries the rest are counted.
    """
    groups: dict[tuple[str, str], list[str]] = {}
    for item in err.errors():
        where = ".".join(str(p) for p in item["loc"]) or "<root>"
        shape = ".".join("*" if isinstance(p, int) else str(p) for p in item["loc"])
        groups.setdefault((shape, item["msg"]), []).append(where)
    parts = []
    for (_, message), places in itertools.islice(groups.items(), MAX_LISTED):
        more = len(places) - 1
        also = f" (and {more} more like it, the last at {places[-1]})" if more else ""
        parts.append(f"{places[0]}: {message}{also}")
    if len(groups) > MAX_LISTED:
        parts.append(f"{len(groups) - MAX_LISTED} more kinds of problem")
    return f"{source}: " + "; ".join(parts)


class Artifact(pydantic.BaseModel):
    """Base of every schema-versioned JSON artifact."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    SCHEMA_VERSION: ClassVar[int] = 1
    #: What to do when the file is not valid JSON (ends the error message).
    BROKEN_FIX: ClassVar[str] = "delete it and re-run the stage that writes it"
    schema_version: int = 1

    def save(self, path: Path) -> None:
        """Write the artifact to ``path`` atomically as indented JSON."""
        write_text_atomic(Path(path), self.model_dump_json(indent=2) + "\n")

    @classmethod
    def load(cls, path: Path) -> Self:
        """Read and validate an artifact.

        Raises:
            WorkspaceError: The file is missing, not JSON, or does not match the schema.
            SchemaVersionError: The file was written by a newer schema version.
        """
        path = Path(path)
        if not path.is_file():
            msg = f"{path} does not exist; run the stage that writes it first"
            raise WorkspaceError(msg)
        raw = read_json(path, fix=cls.BROKEN_FIX)
        version = raw.get("schema_version") if isinstance(raw, dict) else None
        if isinstance(version, int) and version > cls.SCHEMA_VERSION:
            msg = (
                f"{path} has schema_version {version}, but this cam2sim reads {cls.__name__} up "
                f"to version {cls.SCHEMA_VERSION}; upgrade cam2sim (pip install -U cam2sim)"
            )
            raise SchemaVersionError(msg)
        try:
            return cls.model_validate(raw)
        except pydantic.ValidationError as err:
            problems = format_validation_error(err, source=str(path))
            msg = f"{problems}. It does not match this cam2sim's {cls.__name__}: {cls.BROKEN_FIX}"
            raise WorkspaceError(msg) from None
