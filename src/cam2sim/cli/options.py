"""Options more than one command takes: typer annotations and their parsing."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import typer

__all__ = [
    "CarlaHostOption",
    "CarlaPortOption",
    "SimChoice",
    "SimOption",
    "SkipOption",
    "StepsOption",
    "comma_list",
]


class SimChoice(StrEnum):
    """Which simulator runs."""

    BUILTIN = "builtin"
    CARLA = "carla"


StepsOption = Annotated[
    str | None, typer.Option(help="Comma-separated steps to run (default: all).")
]
SkipOption = Annotated[
    str | None, typer.Option(help="Comma-separated steps not to run, e.g. splat,ads.")
]
SimOption = Annotated[SimChoice, typer.Option(help="builtin, or carla (a running CARLA server).")]
CarlaHostOption = Annotated[
    str | None, typer.Option("--carla-host", help="CARLA host (default: config carla.host).")
]
CarlaPortOption = Annotated[
    int | None, typer.Option("--carla-port", help="CARLA port (default: config carla.port).")
]


def comma_list(text: str | None) -> tuple[str, ...]:
    """The non-empty, stripped items of a comma-separated option (``()`` for None)."""
    return tuple(s.strip() for s in (text or "").split(",") if s.strip())
