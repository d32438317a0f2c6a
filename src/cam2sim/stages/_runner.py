"""Bookkeeping shared by every stage: up-to-date checks and recording outcomes."""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cam2sim.core.errors import Cam2SimError

if TYPE_CHECKING:
    from collections.abc import Iterator

    from cam2sim.core.config import Config
    from cam2sim.core.workspace import Workspace, WorldFrameRecord

logger = logging.getLogger(__name__)


@dataclass
class StageRun:
    """Mutable outcome of one stage run, filled in by the stage.

    ``config``: the config the stage ended with, when it changed it (the import's fitted pose
    point); the manifest's snapshot records it instead of the one it started with.
    """

    world: WorldFrameRecord | None = None
    config: Config | None = None


@contextlib.contextmanager
def stage_run(
    ws: Workspace, stage: str, *, inputs_hash: str, config: Config | None
) -> Iterator[StageRun]:
    """Record the outcome of a stage run in the manifest.

    On success the stage is recorded ``done`` with its inputs hash. On an error the stage is
    recorded ``failed`` with the message, and the error propagates. On an interruption
    (``KeyboardInterrupt``) nothing is recorded: the workspace stays as it was.
    """
    started = dt.datetime.now(dt.UTC)
    run = StageRun()
    try:
        yield run
    except (Cam2SimError, OSError, ValueError, RuntimeError) as err:
        ws.record_stage(stage, state="failed", started=started, message=str(err), config=config)
        logger.info("stage %s failed: %s", stage, err)
        raise
    ws.record_stage(
        stage,
        state="done",
        started=started,
        inputs_hash=inputs_hash,
        config=run.config or config,
        world=run.world,
    )
    logger.info("stage %s done", stage)
