"""The evaluate stage: drives scored against the real drive, the reconstruction against reality.

Every caller goes through this module: ``cam2sim evaluate drive`` (any runs, any real drives),
``cam2sim evaluate workspace`` and the pipeline's ``evaluate`` step (a workspace's runs), and
the campaign (its runs per workspace). The report reads what it writes and computes nothing.

- :func:`write_drive_evaluation`: score runs against real drives (the Real group joined by the
  runs in the ground-truth world, :func:`~cam2sim.metrics.behaviour.evaluate_with_real_runs`);
  write ``metrics.json``, ``segment.json``, ``behaviour.md`` (the paper's table) and the figures
  (``trajectories.png``, ``lateral_offset.png``, ``steering.png``).
- :func:`evaluate_workspace_drives`: a workspace's runs against its recorded drive (the
  scenario's reference trajectory) or given real drives. Where one real drive is the only
  reference, its corridor is its line +- the lane's margin (:func:`lane_margin`).
- :func:`evaluate_workspace`: the stage. The drive metrics in ``WS/report/drive/``, the image
  quality of a replay's cameras in ``WS/report/images/`` and the semantic IoU of the world in
  ``WS/report/semantic/`` (:mod:`cam2sim.stages.reconstruction`), where possible. It records
  itself in the manifest as ``evaluate`` with the hash of its inputs and skips when up to date.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

from cam2sim.core.errors import Cam2SimError, StageError
from cam2sim.core.files import write_text_atomic
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.run_record import RunRecord
from cam2sim.core.workspace import hash_inputs, run_paths
from cam2sim.metrics.behaviour import behaviour_table, evaluate_with_real_runs, recorded_drive
from cam2sim.metrics.drive_io import load_run_dir, load_runs
from cam2sim.render.truth import truth_world_path
from cam2sim.report.drive_figures import write_drive_figures
from cam2sim.scenario.model import Scenario
from cam2sim.stages._runner import stage_run
from cam2sim.stages.reconstruction import (
    evaluate_replay_images,
    evaluate_replay_steering,
    evaluate_world_semantics,
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from cam2sim.core.workspace import Workspace
    from cam2sim.metrics.drive_io import DriveRun
    from cam2sim.metrics.drive_quality import DriveEvaluation, DriveOptions, Segment

__all__ = [
    "EVALUATE_STAGE",
    "EvaluateOptions",
    "EvaluateResult",
    "drive_run_ids",
    "evaluate_workspace",
    "evaluate_workspace_drives",
    "lane_margin",
    "write_drive_evaluation",
]

logger = logging.getLogger(__name__)

EVALUATE_STAGE: Final = "evaluate"
"""The stage's name in the manifest."""


@dataclass(frozen=True)
class EvaluateOptions:
    """What the evaluate stage scores.

    Attributes:
        drive_runs: Run ids of the drives to score; None: every drive run of the workspace.
        replay_runs: Run ids of replays whose saved frames are scored against the recorded
            frames (the first one with frames); None: the newest replay with frames.
        real: Real drives (``trajectory*.csv`` files or folders) as references; empty: the
            scenario's recorded drive.
        real_crs: CRS of the real drives' x, y.
        force: Evaluate even when up to date.
    """

    drive_runs: tuple[str, ...] | None = None
    replay_runs: tuple[str, ...] | None = None
    real: tuple[Path, ...] = ()
    real_crs: str = "EPSG:32632"
    force: bool = False


@dataclass(frozen=True)
class EvaluateResult:
    """What the stage wrote.

    Attributes:
        metrics: ``WS/report/drive/metrics.json``.
        notes: What was not computed, and why (no replay frames, no ground-truth world...).
        up_to_date: Nothing was done: the inputs had not changed.
    """

    metrics: Path
    notes: tuple[str, ...] = ()
    up_to_date: bool = False


def write_drive_evaluation(
    real: Sequence[DriveRun],
    runs: Sequence[DriveRun],
    out: Path,
    *,
    segment: Segment | None = None,
    options: DriveOptions | None = None,
) -> DriveEvaluation:
    """Score ``runs`` against the ``real`` drives; write the metrics and figures into ``out``.

    Runs of method ``real`` (driven in the ground-truth world) join the Real group.

    Returns:
        The evaluation (``out/metrics.json`` holds its metrics).
    """
    ev = evaluate_with_real_runs(real, runs, segment=segment, options=options)
    out.mkdir(parents=True, exist_ok=True)
    ev.metrics.save(out / "metrics.json")
    ev.metrics.segment.save(out / "segment.json")
    write_text_atomic(out / "behaviour.md", behaviour_table(ev.metrics).markdown())
    write_drive_figures(ev, out)
    return ev


def _real_drives(ws: Workspace, real: Sequence[Path], real_crs: str) -> list[DriveRun]:
    """The given real drives, else the scenario's recorded drive."""
    if real:
        return load_runs(list(real), real=True, crs=real_crs)

    path = ws.scenario_path
    if not path.is_file():
        msg = f"{ws.root} has no scenario; run `cam2sim scenario {ws.root}` first"
        raise StageError(msg)
    return [recorded_drive(Scenario.load(path), source=str(path))]


def lane_margin(ws: Workspace) -> float | None:
    """How far the car may sit off the recorded line and stay in its lane, metres.

    ``(lane width - car width) / 2``, the lane width being the median width of the driving lane
    nearest to each pose of the recorded drive (``WS/map/map.xodr``), the car's width from
    config.yaml. A corridor of one recorded drive is that drive's line +- this: the published
    corridor (the envelope of the real drives) has no width with one drive.

    Returns:
        The margin (0 where the lane is narrower than the car); None without a map or a
        scenario, or when no driving lane lies within 4 m of the recorded drive.
    """
    import numpy as np  # noqa: PLC0415 -- lazy: the module is imported by the CLI

    from cam2sim.stages.map import load_road_map  # noqa: PLC0415 -- lazy: shapely

    if not (ws.map_xodr_path.is_file() and ws.scenario_path.is_file()):
        return None
    xy = np.asarray(Scenario.load(ws.scenario_path).trajectory.reference, dtype=np.float64)
    near = load_road_map(ws).nearest_lane(xy[:, :2], max_distance=4.0)
    widths = near.width[near.lane >= 0]
    if widths.size == 0:
        return None
    car = ws.load_config().vehicle.width_m
    return max(0.0, (float(np.median(widths)) - car) / 2.0)


def evaluate_workspace_drives(
    ws: Workspace,
    run_ids: Sequence[str],
    out: Path,
    *,
    real: Sequence[Path] = (),
    real_crs: str = "EPSG:32632",
) -> Path:
    """Score a workspace's drive runs; write ``out/metrics.json``, the table and the figures.

    The references are the ``real`` drives, else the scenario's recorded drive (its reference
    point, the point runs are recorded at).

    Returns:
        The ``metrics.json`` path.
    """
    from cam2sim.metrics.drive_quality import DriveOptions  # noqa: PLC0415 -- lazy: numpy

    references = _real_drives(ws, real, real_crs)
    runs = [load_run_dir(ws.runs_dir / r) for r in run_ids]
    options = DriveOptions(single_drive_half_width_m=lane_margin(ws))
    write_drive_evaluation(references, runs, out, options=options)
    return out / "metrics.json"


def drive_run_ids(ws: Workspace) -> list[str]:
    """Ids of the workspace's finished drive runs, oldest first (what evaluate scores)."""
    return _runs_of_kind(ws, "drive")


def _runs_of_kind(ws: Workspace, kind: str) -> list[str]:
    """Ids of the workspace's finished runs of ``kind`` (``drive``, ``replay``), oldest first."""
    found = []
    for folder in ws.iter_runs():
        files = run_paths(folder)
        readable = files.trajectory_csv.is_file() and files.run_json.is_file()
        if readable and RunRecord.load(files.run_json).kind == kind:
            found.append(folder.name)
    return found


def evaluate_workspace(
    ws: Workspace,
    *,
    options: EvaluateOptions | None = None,
    progress: ProgressCallback | None = None,
) -> EvaluateResult:
    """The evaluate stage: drive metrics, image quality and semantic IoU of a workspace.

    Args:
        ws: The workspace.
        options: Which runs and references; defaults score every drive run against the
            recorded drive.
        progress: Receives the image and semantic evaluations' tasks.

    Returns:
        What was written, and notes on what could not be computed.

    Raises:
        StageError: No drive run to score, or no scenario (and no real drives given).
    """
    opts = options or EvaluateOptions()
    runs = list(opts.drive_runs) if opts.drive_runs is not None else _runs_of_kind(ws, "drive")
    if not runs:
        msg = f"{ws.root} has no drive runs to evaluate; run `cam2sim drive {ws.root}` first"
        raise StageError(msg)
    replay = list(opts.replay_runs) if opts.replay_runs is not None else _runs_of_kind(ws, "replay")
    if opts.replay_runs is None:
        replay = [r for r in reversed(replay) if (ws.runs_dir / r / "frames").is_dir()][:1]
    out = ws.drive_eval_dir
    inputs = {
        "scenario": ws.done_inputs_hash("scenario"),
        "runs": runs,
        "replay": replay,
        "corridor": "one drive: lane margin",  # the rule changed: evaluate again
        "policy": _policy_fingerprint(ws),  # the steering agreement's DAVE-2
    }
    if opts.real:
        inputs["real"] = [str(p) for p in opts.real]
    inputs_hash = hash_inputs(inputs)
    metrics = out / "metrics.json"
    if not opts.force and ws.is_up_to_date(EVALUATE_STAGE, inputs_hash) and metrics.is_file():
        logger.info("stage evaluate up to date")
        return EvaluateResult(metrics, up_to_date=True)
    with stage_run(ws, EVALUATE_STAGE, inputs_hash=inputs_hash, config=None):
        evaluate_workspace_drives(ws, runs, out, real=opts.real, real_crs=opts.real_crs)
        notes = _evaluate_reconstruction(ws, replay, progress or no_progress)
    logger.info("stage evaluate: %d drive run(s) scored", len(runs))
    return EvaluateResult(metrics, tuple(notes))


def _dave2(ws: Workspace) -> Path | None:
    """The drives' DAVE-2 (``ads/dave2.onnx``), the steering agreement's policy, if exported."""
    from cam2sim.stages.ads import ONNX_FILE  # noqa: PLC0415

    model = ws.ads_dir / ONNX_FILE
    return model if model.is_file() else None


def _policy_fingerprint(ws: Workspace) -> str | None:
    from cam2sim.core.files import file_fingerprint  # noqa: PLC0415

    model = _dave2(ws)
    return file_fingerprint(model) if model is not None else None


def _replay_steering(ws: Workspace, folder: Path, progress: ProgressCallback) -> list[str]:
    """DAVE-2 on the replay's frames against the recorded ones; notes on what was not done."""
    model = _dave2(ws)
    if model is None:
        return ["no DAVE-2 model (ads/dave2.onnx): steering agreement not computed"]
    try:
        evaluate_replay_steering(ws, folder, ws.report_files.images_dir, model, progress=progress)
    except Cam2SimError as err:
        return [f"steering agreement not computed: {err}"]
    return []


def _evaluate_reconstruction(
    ws: Workspace, replay: list[str], progress: ProgressCallback
) -> list[str]:
    """Image quality of the replay's cameras and semantic IoU of the world, where possible."""
    notes = []
    folder = ws.runs_dir / replay[0] if replay else None
    if folder is None or not (folder / "frames").is_dir():
        notes.append("no replay frames: image quality not computed")
    else:
        try:
            _, note = evaluate_replay_images(
                ws, folder, ws.report_files.images_dir, progress=progress
            )
            notes += [note] if note else []
        except Cam2SimError as err:  # the drive metrics stand without it
            notes.append(f"image quality not computed: {err}")
        notes += _replay_steering(ws, folder, progress)
    if not truth_world_path(ws.root).is_file():
        notes.append("no ground-truth world: semantic IoU not computed")
        return notes
    try:
        evaluate_world_semantics(ws, ws.report_files.semantic_dir, progress=progress)
    except Cam2SimError as err:
        notes.append(f"semantic IoU not computed: {err}")
    return notes
