"""The workspace contract: every artifact path, the manifest, and per-stage state.

This module is the only place that knows where things live inside a workspace folder. Stages ask
a :class:`Workspace` for paths and never build file names of another stage themselves.

Layout::

    WS/
      workspace.json     manifest: tool version, config snapshot, world frame, stage states,
                         the latest `cam2sim run`'s step outcomes (the one state store)
      .workspace.lock    held while one process updates the manifest (read, change, write)
      config.yaml        the user's recording config
      dataset/           stage extract / import
      detections/ map/ scenario/ splat/ ads/ runs/ report/
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal

import pydantic

from cam2sim import __version__
from cam2sim.core.config import Config, load_config, save_config
from cam2sim.core.errors import WorkspaceError
from cam2sim.core.files import waiting_lock
from cam2sim.core.schema import Artifact

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = [
    "LEGACY_PIPELINE_FILE",
    "SCENARIO_FILE",
    "TRUTH_WORLD_FILE",
    "Manifest",
    "StageRecord",
    "StepRecord",
    "StepState",
    "Workspace",
    "WorldFrameRecord",
    "hash_inputs",
]

logger = logging.getLogger(__name__)

StageState = Literal["done", "failed"]
StepState = Literal["done", "skipped", "up_to_date", "failed", "not_applicable"]


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def hash_inputs(data: object) -> str:
    """Return a stable SHA-256 of JSON-serialisable ``data`` (a stage's inputs)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


class StageRecord(pydantic.BaseModel):
    """The outcome of a stage's last run."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    state: StageState
    inputs_hash: str | None = None
    started: dt.datetime
    finished: dt.datetime
    message: str | None = None
    tool_version: str = __version__
    runs: tuple[str, ...] = pydantic.Field(
        (), description="Run folders (WS/runs/<id>) the stage made: replay and drive"
    )


class StepRecord(pydantic.BaseModel):
    """The outcome of one step of the latest ``cam2sim run`` (the report's step timings)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    state: StepState
    seconds: float = 0.0
    message: str = ""
    finished: dt.datetime = pydantic.Field(default_factory=_now)


class WorldFrameRecord(pydantic.BaseModel):
    """The workspace's world frame, fixed once and never changed."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    proj_string: str | None = pydantic.Field(
        description="pyproj string of the world frame; null for a local frame without geo-reference"
    )
    origin_lat_deg: float | None = None
    origin_lon_deg: float | None = None
    origin_alt_m: float = 0.0
    source_crs: str | None = pydantic.Field(
        None, description="CRS the recording's positions were given in"
    )

    @property
    def georeferenced(self) -> bool:
        """Whether world coordinates can be mapped to the Earth."""
        return self.proj_string is not None


class Manifest(Artifact):
    """``workspace.json``."""

    BROKEN_FIX: ClassVar[str] = (
        "it records which stages ran: restore it from a backup, or move it aside and "
        "re-create the workspace with `cam2sim init` (keep a copy of config.yaml: init writes "
        "a new one)"
    )

    tool_version: str = __version__
    created: dt.datetime = pydantic.Field(default_factory=_now)
    config: dict[str, object] | None = pydantic.Field(
        None, description="Snapshot of config.yaml at the last stage run"
    )
    world: WorldFrameRecord | None = None
    stages: dict[str, StageRecord] = pydantic.Field(default_factory=dict)
    steps: dict[str, StepRecord] = pydantic.Field(
        default_factory=dict,
        description="The latest cam2sim run: each step's outcome, in pipeline order",
    )


LEGACY_PIPELINE_FILE = "pipeline.json"
"""``WS/runs/pipeline.json``: where an older cam2sim kept the pipeline's runs and steps.

It is read once, merged into the manifest (the one state store) and removed."""


class _LegacyRuns(pydantic.BaseModel):
    """An entry of the old ``pipeline.json``: the inputs a step last ran with, its runs."""

    model_config = pydantic.ConfigDict(extra="ignore", frozen=True)

    inputs: str | None = None
    runs: tuple[str, ...] = ()


class _LegacyStep(pydantic.BaseModel):
    """A step outcome of the old ``pipeline.json`` (``finished``: ISO 8601 text)."""

    model_config = pydantic.ConfigDict(extra="ignore", frozen=True)

    state: StepState
    seconds: float = 0.0
    message: str = ""
    finished: str = ""

    def record(self, when: dt.datetime) -> StepRecord:
        """The step as a manifest record (``when`` where its time is unreadable)."""
        try:
            finished = dt.datetime.fromisoformat(self.finished)
        except ValueError:
            finished = when
        if finished.tzinfo is None:
            finished = finished.replace(tzinfo=dt.UTC)
        return StepRecord(
            state=self.state, seconds=self.seconds, message=self.message, finished=finished
        )


class _LegacyPipelineState(Artifact):
    """The old ``WS/runs/pipeline.json`` (no ``schema_version``: version 1)."""

    model_config = pydantic.ConfigDict(extra="ignore", frozen=True)

    replay: _LegacyRuns | None = None
    drive: _LegacyRuns | None = None
    evaluate: _LegacyRuns | None = None
    steps: dict[str, _LegacyStep] = pydantic.Field(default_factory=dict)

    def merged_into(self, manifest: Manifest, *, when: dt.datetime) -> Manifest:
        """``manifest`` with what the old file knew that it does not (the manifest wins)."""
        stages = dict(manifest.stages)
        for name in ("replay", "drive", "evaluate"):
            entry: _LegacyRuns | None = getattr(self, name)
            if entry is None or entry.inputs is None or name in stages:
                continue
            stages[name] = StageRecord(
                state="done", inputs_hash=entry.inputs, started=when, finished=when,
                runs=entry.runs,
            )  # fmt: skip
        steps = {name: step.record(when) for name, step in self.steps.items()}
        steps |= manifest.steps
        return manifest.model_copy(update={"stages": stages, "steps": steps})


SCENARIO_FILE = "scenario.json"
TRUTH_WORLD_FILE = Path("truth") / "world.json"
"""The ground-truth world of a workspace, relative to its root (``cam2sim demo`` writes it)."""
"""The scenario's file name in ``scenario/``."""


class Workspace:
    """A cam2sim workspace folder and the paths of all its artifacts."""

    MANIFEST = "workspace.json"
    CONFIG = "config.yaml"
    LOCK = ".workspace.lock"

    def __init__(self, root: Path) -> None:
        self.root = Path(root).absolute()

    def __repr__(self) -> str:
        return f"Workspace({str(self.root)!r})"

    # -- creation and opening -------------------------------------------------------------
    @classmethod
    def create(
        cls, root: Path, config: Config, *, comment: str = "", force: bool = False
    ) -> Workspace:
        """Create a new workspace with a config and an empty manifest.

        Raises:
            WorkspaceError: ``root`` already holds a workspace and ``force`` is false.
        """
        ws = cls(root)
        if ws.manifest_path.exists() and not force:
            msg = (
                f"{ws.root} already holds a cam2sim workspace; edit its config.yaml, or pass "
                "--force to overwrite the config"
            )
            raise WorkspaceError(msg)
        ws.root.mkdir(parents=True, exist_ok=True)
        save_config(config, ws.config_path, comment=comment)
        manifest = ws.read_manifest() if ws.manifest_path.exists() else Manifest()
        ws.write_manifest(manifest)
        return ws

    @classmethod
    def open(cls, root: Path) -> Workspace:
        """Open an existing workspace (its manifest read and checked).

        Raises:
            WorkspaceError: ``root`` is not a workspace, or its manifest is broken.
            SchemaVersionError: A newer cam2sim wrote the workspace.
        """
        ws = cls(root)
        if not ws.manifest_path.is_file():
            inner = Path(root) / "ws"
            if (inner / cls.MANIFEST).is_file():  # a cam2sim demo's -o folder
                msg = (
                    f"{ws.root} is not a workspace but holds one: {inner} (cam2sim demo puts the "
                    f"workspace in OUT/ws); pass {inner}"
                )
                raise WorkspaceError(msg)
            msg = (
                f"{ws.root} is not a cam2sim workspace (no {cls.MANIFEST}); create one with "
                f"`cam2sim init {root} --bag BAG` or `cam2sim import {root} --images DIR`"
            )
            raise WorkspaceError(msg)
        ws.read_manifest()
        return ws

    # -- manifest and config ----------------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        """``workspace.json``."""
        return self.root / self.MANIFEST

    @property
    def config_path(self) -> Path:
        """``config.yaml``."""
        return self.root / self.CONFIG

    @contextlib.contextmanager
    def _updating(self) -> Iterator[None]:
        """Hold the manifest's lock while reading, changing and writing it.

        Steps of one ``cam2sim run`` record themselves from more than one process at a time
        (DAVE-2 trains in its own process beside the splat on a GPU): without the lock one
        process's read-change-write could drop the other's record (a lost splat record trains
        the splat again). It holds between processes and threads alike.
        """
        with waiting_lock(self.root / self.LOCK):
            yield

    def read_manifest(self) -> Manifest:
        """Load and validate ``workspace.json``.

        A workspace of an older cam2sim that kept the pipeline's state in
        ``WS/runs/pipeline.json`` has it merged into the manifest here, once.
        """
        manifest = Manifest.load(self.manifest_path)
        legacy = self.runs_dir / LEGACY_PIPELINE_FILE
        if legacy.is_file():
            manifest = self._merge_legacy_pipeline(manifest, legacy)
        return manifest

    def _merge_legacy_pipeline(self, manifest: Manifest, legacy: Path) -> Manifest:
        """Move the old ``pipeline.json`` into the manifest and remove it.

        A broken file is dropped with a warning in the log: replay and drive then run again,
        as they did when it was the pipeline's own file.
        """
        try:
            state = _LegacyPipelineState.load(legacy)
        except WorkspaceError as err:
            logger.warning("%s is unreadable (%s); replay and drive run again", legacy, err)
        else:
            when = dt.datetime.fromtimestamp(legacy.stat().st_mtime, dt.UTC)
            manifest = state.merged_into(manifest, when=when)
            self.write_manifest(manifest)
        with contextlib.suppress(FileNotFoundError):  # another process merged it first
            legacy.unlink()
        return manifest

    def write_manifest(self, manifest: Manifest) -> None:
        """Write ``workspace.json`` atomically."""
        manifest.save(self.manifest_path)

    def load_config(self) -> Config:
        """Load and validate ``config.yaml``."""
        return load_config(self.config_path)

    def resolve(self, path: str | Path) -> Path:
        """Resolve a path from the config: relative paths are relative to the workspace."""
        path = Path(path).expanduser()
        return path if path.is_absolute() else (self.root / path)

    def stage_record(self, stage: str) -> StageRecord | None:
        """Return the last recorded outcome of ``stage``, if any."""
        return self.read_manifest().stages.get(stage)

    def done_inputs_hash(self, stage: str) -> str | None:
        """The inputs hash of ``stage``'s last success, or None when it has not succeeded.

        What a later stage's inputs name, so that it runs again when this one's output changed.
        """
        record = self.stage_record(stage)
        return None if record is None or record.state != "done" else record.inputs_hash

    def is_up_to_date(self, stage: str, inputs_hash: str) -> bool:
        """Whether ``stage`` last succeeded with exactly these inputs."""
        return inputs_hash == self.done_inputs_hash(stage)

    def record_stage(
        self,
        stage: str,
        *,
        state: StageState,
        started: dt.datetime,
        inputs_hash: str | None = None,
        message: str | None = None,
        config: Config | None = None,
        world: WorldFrameRecord | None = None,
        runs: tuple[str, ...] = (),
    ) -> None:
        """Record a stage outcome in the manifest (atomically, under the manifest's lock)."""
        with self._updating():
            manifest = self.read_manifest()
            stages = dict(manifest.stages)
            stages[stage] = StageRecord(
                state=state,
                inputs_hash=inputs_hash,
                started=started,
                finished=_now(),
                message=message,
                runs=runs,
            )
            update: dict[str, object] = {"stages": stages, "tool_version": __version__}
            if config is not None:
                update["config"] = config.model_dump(mode="json")
            if world is not None:
                update["world"] = world
            self.write_manifest(manifest.model_copy(update=update))

    def record_step(self, step: str, *, state: StepState, seconds: float, message: str) -> None:
        """Record the outcome of a ``cam2sim run`` step (atomically, under the manifest's lock)."""
        record = StepRecord(state=state, seconds=round(seconds, 3), message=message)
        with self._updating():
            manifest = self.read_manifest()
            steps = {**manifest.steps, step: record}
            self.write_manifest(manifest.model_copy(update={"steps": steps}))

    def world_frame(self) -> WorldFrameRecord | None:
        """The workspace's world frame, once a stage has fixed it."""
        return self.read_manifest().world

    # -- stage folders and artifacts ----------------------------------------------------------
    @property
    def dataset_dir(self) -> Path:
        """Stage extract/import output folder."""
        return self.root / "dataset"

    @property
    def detections_dir(self) -> Path:
        """Stage detect output folder."""
        return self.root / "detections"

    @property
    def map_dir(self) -> Path:
        """Stage map output folder."""
        return self.root / "map"

    @property
    def map_xodr_path(self) -> Path:
        """``map/map.xodr``: the road map every later stage queries."""
        return self.map_files.xodr

    @property
    def scenario_dir(self) -> Path:
        """Stage scenario output folder."""
        return self.root / "scenario"

    @property
    def scenario_path(self) -> Path:
        """``scenario/scenario.json``: the scenario every run reads."""
        return self.scenario_dir / SCENARIO_FILE

    @property
    def splat_dir(self) -> Path:
        """Stage splat output folder."""
        return self.root / "splat"

    @property
    def ads_dir(self) -> Path:
        """Steering model weights and training logs."""
        return self.root / "ads"

    @property
    def runs_dir(self) -> Path:
        """Replay and closed-loop runs, one folder each."""
        return self.root / "runs"

    def iter_runs(self) -> Iterator[Path]:
        """The finished run folders (``runs/<run-id>/``), oldest first; half-built ones hidden."""
        if not self.runs_dir.is_dir():
            return
        yield from sorted(
            p for p in self.runs_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
        )

    @property
    def report_dir(self) -> Path:
        """Metrics and the HTML report."""
        return self.root / "report"

    @property
    def drive_eval_dir(self) -> Path:
        """``report/drive/``: the evaluate stage's drive metrics, table and figures.

        ``metrics.json``, ``segment.json``, ``behaviour.md`` and the PNG figures; the report
        reads them.
        """
        return self.report_dir / "drive"

    @property
    def truth_world_json(self) -> Path:
        """``truth/world.json``: the ground-truth world, where there is one (the demo's)."""
        return self.root / TRUTH_WORLD_FILE

    @property
    def real_dir(self) -> Path:
        """``real/``: further recorded drives of the street, read as Real by evaluate."""
        return self.root / "real"

    @property
    def video_scratch_dir(self) -> Path:
        """``.video_frames.partial/``: a video's decoded frames while ``cam2sim import`` runs."""
        return self.root / ".video_frames.partial"

    @property
    def detection_files(self) -> DetectionPaths:
        """The detect stage's files."""
        return DetectionPaths(self.detections_dir)

    @property
    def map_files(self) -> MapPaths:
        """The map stage's files."""
        return MapPaths(self.map_dir)

    @property
    def splat_files(self) -> SplatPaths:
        """The splat stage's files."""
        return SplatPaths(self.splat_dir)

    @property
    def ads_files(self) -> AdsPaths:
        """The system under test's files."""
        return AdsPaths(self.ads_dir)

    @property
    def report_files(self) -> ReportPaths:
        """The evaluate stage's and the report's files."""
        return ReportPaths(self.report_dir)


class DetectionPaths:
    """Paths of the detect stage's pictures and locks (``WS/detections/``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def picture(self) -> Path:
        """The bird's-eye picture of the parked vehicles."""
        return self.root / "parked_vehicles.png"

    @property
    def editor_lock(self) -> Path:
        """Held while ``cam2sim refine`` edits the list (one editor per workspace)."""
        return self.root / ".editor.lock"


class MapPaths:
    """Paths of the map stage's artifacts (``WS/map/``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def xodr(self) -> Path:
        """The OpenDRIVE road map every later stage queries."""
        return self.root / "map.xodr"

    @property
    def report_json(self) -> Path:
        """Where the roads came from and how the route lies on them."""
        return self.root / "map_report.json"

    @property
    def source_osm(self) -> Path:
        """The OSM data converted (absent for a road along the driven path)."""
        return self.root / "source.osm"


class SplatPaths:
    """Paths of the splat stage's artifacts (``WS/splat/``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def prep_dir(self) -> Path:
        """The prepared scene (``scene.json``, ``images/``, masks, points)."""
        return self.root / "prep"

    @property
    def prep_images_dir(self) -> Path:
        """The prepared frames the splat trains and is scored on, ``NNNNNN.png``."""
        return self.prep_dir / "images"

    @property
    def models_dir(self) -> Path:
        """One model per chunk, ``chunk_XX.pt`` with its ``chunk_XX.json`` header.

        ``results/`` keeps each trained chunk's training result (a failed training resumes).
        """
        return self.root / "models"

    @property
    def eval_json(self) -> Path:
        """The evaluation: held out, offsets, against the truth and a rig's cameras."""
        return self.root / "eval.json"

    @property
    def renders_dir(self) -> Path:
        """The splat's render of each held-out frame, ``NNNNNN.webp``."""
        return self.root / "renders"


class AdsPaths:
    """Paths of the system under test's artifacts (``WS/ads/``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def onnx(self) -> Path:
        """The exported DAVE-2 the drives load."""
        return self.root / "dave2.onnx"

    @property
    def train_figure(self) -> Path:
        """DAVE-2's training curve and validation predictions."""
        return self.root / "train_report.png"


class ReportPaths:
    """Paths of the evaluate stage's and the report's artifacts (``WS/report/``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def html(self) -> Path:
        """The self-contained HTML report."""
        return self.root / "report.html"

    @property
    def metrics_json(self) -> Path:
        """The drive metrics (``drive/metrics.json``)."""
        return self.root / "drive" / "metrics.json"

    @property
    def images_dir(self) -> Path:
        """Image quality of the replay's cameras against the recorded frames."""
        return self.root / "images"

    @property
    def semantic_dir(self) -> Path:
        """Semantic IoU of the reconstructed world against the truth."""
        return self.root / "semantic"

    @property
    def tables_dir(self) -> Path:
        """The report's tables as CSV and LaTeX."""
        return self.root / "tables"


def run_paths(run_dir: Path) -> RunPaths:
    """Return the artifact paths inside one run folder (``WS/runs/<id>/``, or one being built)."""
    return RunPaths(Path(run_dir))


class RunPaths:
    """Paths of one replay or drive run's artifacts, relative to its folder."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def trajectory_csv(self) -> Path:
        """``t, x, y, z, heading, speed, steering, wheel_angle`` of every simulator step."""
        return self.root / "trajectory.csv"

    @property
    def steering_csv(self) -> Path:
        """The policy's decisions ``t, value``."""
        return self.root / "steering.csv"

    @property
    def events_json(self) -> Path:
        """What happened during the run (collisions, off-road, route completed, ...)."""
        return self.root / "events.json"

    @property
    def run_json(self) -> Path:
        """What was run: method, camera, policy, seed, options, variation, outcome."""
        return self.root / "run.json"

    def frames_dir(self, camera: str) -> Path:
        """Saved frames of ``camera`` (on request)."""
        return self.root / "frames" / camera

    @property
    def side_by_side_dir(self) -> Path:
        """Saved side-by-side images of every camera (on request)."""
        return self.root / "side_by_side"

    @property
    def video(self) -> Path:
        """The side-by-side video (on request)."""
        return self.root / "video.mp4"


def dataset_paths(dataset_dir: Path) -> DatasetPaths:
    """Return the artifact paths inside a dataset folder (also a temporary one being built)."""
    return DatasetPaths(Path(dataset_dir))


class DatasetPaths:
    """Paths of the dataset artifacts, relative to a dataset folder."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @property
    def frames_dir(self) -> Path:
        """Camera frames, ``NNNNNN.png`` or ``.jpg``."""
        return self.root / "frames"

    def frame_file(self, index: int, fmt: str) -> Path:
        """The image file of frame ``index``."""
        suffix = "jpg" if fmt == "jpeg" else fmt
        return self.frames_dir / f"{index:06d}.{suffix}"

    @property
    def poses_csv(self) -> Path:
        """The ego pose at every kept camera frame."""
        return self.root / "poses.csv"

    @property
    def frames_csv(self) -> Path:
        """Frame index and times of a pose-less dataset (images without poses)."""
        return self.root / "frames.csv"

    @property
    def trajectory_csv(self) -> Path:
        """Every ego pose sample of the recording, in the world frame."""
        return self.root / "trajectory.csv"

    @property
    def lidar_dir(self) -> Path:
        """LiDAR scans, ``NNNNNN.npy`` structured arrays in the sensor frame."""
        return self.root / "lidar"

    def lidar_file(self, index: int) -> Path:
        """The point file of scan ``index``."""
        return self.lidar_dir / f"{index:06d}.npy"

    @property
    def lidar_csv(self) -> Path:
        """One row per LiDAR scan: time, sensor pose in the world, point count."""
        return self.root / "lidar.csv"

    @property
    def signals_dir(self) -> Path:
        """Scalar signal tables, ``<name>.csv``."""
        return self.root / "signals"

    def signal_file(self, name: str) -> Path:
        """The table of signal ``name``."""
        return self.signals_dir / f"{name}.csv"

    @property
    def calibration_json(self) -> Path:
        """Camera intrinsics, distortion, size and sensor mounts."""
        return self.root / "calibration.json"

    @property
    def rig_dir(self) -> Path:
        """The rig's other cameras (beside the front one), one folder each."""
        return self.root / "cameras"

    def rig_camera_json(self, name: str) -> Path:
        """Rig camera ``name``'s intrinsics and pose on the front camera."""
        return self.rig_dir / name / "camera.json"

    def rig_frame_file(self, name: str, index: int, fmt: str) -> Path:
        """Rig camera ``name``'s image at front frame ``index``."""
        suffix = "jpg" if fmt == "jpeg" else fmt
        return self.rig_dir / name / "frames" / f"{index:06d}.{suffix}"

    @property
    def dataset_json(self) -> Path:
        """Counts, time span, dropped frames and why, source fingerprints."""
        return self.root / "dataset.json"


__all__ += [
    "AdsPaths",
    "DatasetPaths",
    "DetectionPaths",
    "MapPaths",
    "ReportPaths",
    "SplatPaths",
    "dataset_paths",
]
