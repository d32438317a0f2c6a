"""``cam2sim run``: every stage in order, resuming where an earlier run stopped.

The pipeline calls the stage functions (extract, map, detect, scenario, splat, ads, replay,
drive, evaluate, report) with defaults. Stages that record themselves in the manifest skip on
their own when up to date; the pipeline notices (their record did not change) and reports them
``up_to_date``. Replay and drive write a new run folder each time, so the pipeline remembers the
runs it made in the workspace manifest (the ``replay`` and ``drive`` stage records: the
inputs hash and the run ids), and makes them again only when the scenario or the options
changed (or a run folder disappeared). The manifest also keeps the latest outcome of every step
that ran (``Manifest.steps``: state, seconds, message), which the report's summary lists. The
manifest is the workspace's one state store; an older ``WS/runs/pipeline.json`` is merged into
it when read (:meth:`~cam2sim.core.workspace.Workspace.read_manifest`).

On a GPU machine the ads step (DAVE-2) trains in its own process while the splat step runs
(:class:`~cam2sim.core.sidecar.Sidecar`; ``PipelineOptions.ads_beside_splat``): neither reads
what the other writes, and the splat's preparation leaves the GPU idle for minutes. The detect
and scenario steps run there first (the splat reads neither), so the splat starts right after
the map (:data:`BESIDE_SPLAT_STEPS`). Their outcomes are taken where the ads step stands in the
order, and listed in the usual order, so the summary reads the same; a detect or scenario that
fails there stops the steps after the ads step (the splat has trained by then, and is kept for
the next run). After DAVE-2 that process also drives the runs of the cameras that need no splat
(truth, raster: :data:`EARLY_CAMERAS`, recorded as :data:`EARLY_DRIVES`); the drive step takes
them and drives the splat camera's.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

from cam2sim.core.dataset import NO_INTRINSICS_HINT, Calibration, DatasetInfo
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.files import file_fingerprint, write_text_atomic
from cam2sim.core.machine import available_cpus, children_allotted
from cam2sim.core.progress import ProgressCallback, no_progress, serialized
from cam2sim.core.sidecar import Sidecar
from cam2sim.core.workspace import StepState, dataset_paths, hash_inputs, run_paths
from cam2sim.render.truth import truth_world_path
from cam2sim.scenario.model import Scenario
from cam2sim.stages.ads import TRAIN_STAGE, derive_steering, export_ads, train_ads
from cam2sim.stages.detect import DetectOptions, run_detect
from cam2sim.stages.evaluate import (
    EVALUATE_STAGE,
    EvaluateOptions,
    EvaluateResult,
    evaluate_workspace,
)
from cam2sim.stages.extract import extract
from cam2sim.stages.map import MapOptions, build_map
from cam2sim.stages.runs import (
    DriveOptions,
    ReplayOptions,
    default_judge,
    drive,
    replay,
    stood_still_m,
)
from cam2sim.stages.scenario import run_scenario
from cam2sim.stages.splat import SplatStageOptions, run_splat

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from cam2sim.core.workspace import Workspace
    from cam2sim.stages.cameras import CameraName
    from cam2sim.stages.splat import SplatResult
    from cam2sim.stages.variation import RunVariation

__all__ = [
    "STEPS",
    "PipelineOptions",
    "PipelineResult",
    "StepOutcome",
    "StepState",
    "default_drive_workers",
    "remember_inputs",
    "run_pipeline",
]

logger = logging.getLogger(__name__)

STEPS: Final = (
    "extract",
    "map",
    "detect",
    "scenario",
    "splat",
    "ads",
    "replay",
    "drive",
    "evaluate",
    "report",
)


CPU_SPLAT_REPLAY_FRAMES: Final = 500
"""Most frames ``cam2sim run`` replays with the splat camera on a CPU (by default): about 0.5 s
a frame for the raster and splat cameras at 1242x375 on 2 cores, so KITTI 03's 801 frames took
426 s of replay and 354 s of image scoring (docs/benchmarks.md); a recording of several minutes
would take hours."""


BESIDE_MIN_CPUS: Final = 8
"""Fewest CPUs on which ``cam2sim run`` trains DAVE-2 beside the splat by default (the splat's
preparation, SIFT and triangulation, takes every core it has; DAVE-2 needs a few for its
frames)."""
BESIDE_SPLAT_CPUS: Final = 4
"""CPUs the ads step leaves the splat step when it trains beside it: the host loops of up to
three chunk workers training on the GPU, and this process (DAVE-2 with a thread a core beside
them took 35 s an epoch where it takes 0.5 s alone: docs/benchmarks.md)."""


EARLY_CAMERAS: Final = frozenset({"truth", "raster"})
"""Cameras whose closed-loop runs need no splat: where DAVE-2 trains beside the splat, they
drive there after it while the splat still trains (:meth:`_Pipeline.drive_early`)."""

BESIDE_SPLAT_STEPS: Final = ("detect", "scenario", "ads")
"""The steps that run in the process beside the splat where DAVE-2 trains there: the splat
reads none of their results, and their outcomes are taken where the ads step stands."""

EARLY_DRIVES: Final = "drive_early"
"""The manifest's record of the runs driven beside the splat (their inputs and run ids)."""


def replay_stride(samples: int, cameras: Sequence[str], *, cuda: bool) -> int:
    """Every how many recorded frames ``cam2sim run`` replays by default.

    1, or on a CPU with the splat camera the stride that keeps at most
    :data:`CPU_SPLAT_REPLAY_FRAMES` frames.
    """
    if cuda or "splat" not in cameras:
        return 1
    return max(1, math.ceil(samples / CPU_SPLAT_REPLAY_FRAMES))


@dataclass(frozen=True)
class PipelineOptions:
    """What ``cam2sim run`` does.

    Attributes:
        osm: OSM file for the map; None downloads the route's area from Overpass.
        steps: Steps to run, a subset of :data:`STEPS` (order is always the pipeline's).
        skip: Steps not to run (applied after ``steps``).
        detect_model: Camera detector for recordings without LiDAR; None: detect only from
            LiDAR (``detect`` is not applicable without it).
        policy: Drive policy; None: the DAVE-2 ONNX the workspace has (unless ``skip`` holds
            ``ads``), else ``pure-pursuit``.
        cameras: Cameras for replay and drive; None: ``raster``, plus ``splat`` when splat
            models exist, plus (drive only) ``truth`` when the workspace has a ground-truth world
            (``WS/truth/world.json``; its runs are real-world runs). ``("none",)`` renders
            nothing (fast; pure-pursuit only).
        runs: Drive runs per camera (seeds ``run_seed``, ``run_seed + 1``, ...).
        run_seed: Seed of each camera's first drive run: what its start offset, speed and
            steering noise are drawn from (the same seed, the same draw, for every camera: runs
            of one seed are paired). A benchmark gives each street its own
            (:attr:`~cam2sim.campaign.suite.WorldSpec.run_seed`), so that the streets' runs are
            independent draws.
        replay_every: Replay every n-th recorded frame (the report's frames and the image
            quality are computed on them). None: every frame, except with the splat camera
            and no CUDA, where every n-th keeps the replay within
            :data:`CPU_SPLAT_REPLAY_FRAMES` frames (:func:`replay_stride`).
        steering_noise_std: Steering noise of the builtin simulator (steering units per step,
            seeded per run), so that repeated runs of a deterministic policy differ.
        run_variation: Seeded start-pose and speed differences between drive runs
            (:mod:`cam2sim.stages.variation`); None: none.
        recorded_speed: The drives follow the recorded speed along the route (see
            :class:`~cam2sim.stages.runs.DriveOptions`) instead of holding the start speed.
            None: they do when the recording changes speed (by more than
            :data:`~cam2sim.sim.speed.SPEED_CHANGE_SHARE` of its start speed somewhere, as a
            real driver slowing for a turn); a drive at one speed (the synthetic ones) holds it.
        splat: Splat options; None: :meth:`SplatStageOptions.for_run
            <cam2sim.stages.splat.SplatStageOptions.for_run>` (its points triangulated from
            the frames when there is no LiDAR).
        splat_on_cpu: Train splats without a GPU (the CPU preset: minutes a chunk); False makes
            ``splat`` not applicable there.
        bundle_adjust: Adjust the recorded poses to the frames before the splat trains (a
            pose-prior bundle adjustment; the held-out frames are then aligned to their own
            images, as pose-free 3DGS papers evaluate); None: a real recording's poses (a demo
            world's exact ones are kept), see :attr:`PrepareOptions.refine_poses
            <cam2sim.splat.prepare.PrepareOptions.refine_poses>`. Only with the run's own splat
            preset (``splat`` None).
        steering_signal: Signal the ads step trains on; None: ``steering``, else the first
            signal whose name holds ``steer``.
        continue_on_error: Go on after a failed step (later steps may then fail too).
        ads: DAVE-2 training options (None: :meth:`TrainOptions.same_street
            <cam2sim.ads.train_options.TrainOptions.same_street>`, on the steering signal chosen).
        judge: Where the drives' leaving the road and collisions are judged (see
            :class:`~cam2sim.stages.runs.DriveOptions`); None: in the ground-truth world when
            the workspace has one (every camera's runs alike), else on the map.
        real: Further recorded drives of the same street (``trajectory*.csv`` files or folders)
            that join the recorded one in the Real column, as the paper's three real drives.
        real_crs: CRS of their x, y.
        report_frames: Keep the camera frames of each camera's first closed-loop run, for the
            report's frames of every method (and the moment a run fails).
        save_frames: Keep the camera frames of every closed-loop run (``cam2sim bench`` shows
            the frames at a failure).
        drive_workers: Processes the drive step runs its cameras' runs in (one camera each);
            None: :func:`default_drive_workers`. The runs are seeded, so their results do not
            depend on it.
        ads_beside_splat: Train DAVE-2 in its own process while the splat trains (neither
            reads what the other writes; the ads step's time then hides behind the splat's);
            None: on a CUDA machine with at least :data:`BESIDE_MIN_CPUS` CPUs. On a laptop's
            few cores the two would only slow each other. Seeded either way: the model is the
            same.
    """

    osm: Path | None = None
    steps: tuple[str, ...] = STEPS
    skip: tuple[str, ...] = ()
    detect_model: str | None = None
    policy: str | None = None
    cameras: tuple[CameraName, ...] | None = None
    runs: int = 3
    run_seed: int = 0
    replay_every: int | None = None
    steering_noise_std: float = 0.0
    run_variation: RunVariation | None = None
    recorded_speed: bool | None = None
    splat: SplatStageOptions | None = None
    splat_on_cpu: bool = True
    bundle_adjust: bool | None = None
    steering_signal: str | None = None
    continue_on_error: bool = False
    ads: Any = None
    judge: Literal["map", "truth"] | None = None
    save_frames: bool = False
    report_frames: bool = True
    real: tuple[Path, ...] = ()
    real_crs: str = "EPSG:32632"
    drive_workers: int | None = None
    ads_beside_splat: bool | None = None

    def __post_init__(self) -> None:
        unknown = sorted((set(self.steps) | set(self.skip)) - set(STEPS))
        if unknown:
            msg = f"unknown step(s) {', '.join(unknown)}; choose from {', '.join(STEPS)}"
            raise ConfigError(msg)
        cameras = sorted(set(self.cameras or ()) - {"raster", "splat", "truth", "carla", "none"})
        if cameras:
            msg = f"unknown camera(s) {', '.join(cameras)}; choose from raster, splat, truth, none"
            raise ConfigError(msg)
        if self.runs < 1 or (self.replay_every is not None and self.replay_every < 1):
            msg = f"runs and replay_every must be >= 1, got {self.runs}, {self.replay_every}"
            raise ConfigError(msg)

    def wants(self, step: str) -> bool:
        """Whether ``step`` is selected."""
        return step in self.steps and step not in self.skip


@dataclass(frozen=True)
class StepOutcome:
    """What one step did.

    Attributes:
        name: The step (one of :data:`STEPS`).
        state: ``done`` (ran), ``up_to_date`` (nothing to do), ``skipped`` (not selected, or
            an earlier step failed), ``not_applicable`` (the recording does not allow it) or
            ``failed``.
        seconds: Wall time of the step.
        message: Why (not applicable, skipped, failed) or what it produced.
    """

    name: str
    state: StepState
    seconds: float = 0.0
    message: str = ""


@dataclass(frozen=True)
class PipelineResult:
    """Every step's outcome, in order, and the report's path when one was written."""

    outcomes: tuple[StepOutcome, ...]
    report: Path | None = None

    @property
    def failed(self) -> bool:
        """Whether a step failed."""
        return any(o.state == "failed" for o in self.outcomes)

    def outcome(self, name: str) -> StepOutcome:
        """The outcome of step ``name``."""
        for o in self.outcomes:
            if o.name == name:
                return o
        msg = f"no step {name!r}; steps are {', '.join(STEPS)}"
        raise KeyError(msg)


def _splat_summary(result: SplatResult) -> str:
    """Which device and rasterizer trained the splat, how long, and its held-out quality."""
    parts = []
    if result.trained is not None and result.trained.chunks:
        first = result.trained.chunks[0]
        steps = "/".join(str(c.steps) for c in result.trained.chunks)
        parts.append(
            f"trained on {first.device} ({first.backend}): {steps} steps in "
            f"{result.trained.seconds:.0f} s"
        )
    ev = result.evaluation
    if ev is not None and ev.psnr_db.mean is not None:
        quality = f"held-out {ev.psnr_db.mean:.1f} dB"
        if ev.ssim.mean is not None:
            quality += f", SSIM {ev.ssim.mean:.3f}"
        if ev.lpips.mean is not None:
            quality += f", LPIPS {ev.lpips.mean:.3f}"
        parts.append(quality)
    if result.seconds:
        parts.append(", ".join(f"{k} {v:.1f} s" for k, v in result.seconds.items()))
    return "; ".join(parts)


class _NotApplicableError(Exception):
    """A step the recording or the machine does not allow (the message says why)."""


@dataclass
class _Step:
    """A step's verdict, filled in by the step."""

    up_to_date: bool = False
    message: str = ""


@dataclass
class _Pipeline:
    ws: Workspace
    options: PipelineOptions
    progress: ProgressCallback
    report: Path | None = None

    # -- bookkeeping ------------------------------------------------------------------------
    def _finished(self, stage: str) -> object:
        record = self.ws.stage_record(stage)
        return None if record is None else (record.state, record.finished)

    def _recorded(self, stage: str, call: Callable[[], object], step: _Step) -> None:
        """Run a self-recording stage; up to date when its record did not change."""
        before = self._finished(stage)
        call()
        step.up_to_date = before is not None and self._finished(stage) == before

    def record(self, outcome: StepOutcome) -> None:
        """Keep a step's latest outcome in the manifest (the report's step timings)."""
        self.ws.record_step(
            outcome.name, state=outcome.state, seconds=outcome.seconds, message=outcome.message
        )

    def _made_runs(self, stage: str) -> list[str]:
        """The runs the pipeline's last successful ``stage`` (replay, drive) made."""
        record = self.ws.stage_record(stage)
        return [] if record is None or record.state != "done" else list(record.runs)

    def _runs_current(self, key: str, inputs: str) -> list[str] | None:
        record = self.ws.stage_record(key)
        if record is None or record.state != "done" or record.inputs_hash != inputs:
            return None
        runs = list(record.runs)
        done = (run_paths(self.ws.runs_dir / r).trajectory_csv.is_file() for r in runs)
        if not runs or not all(done):
            return None
        return runs

    def _camera_inputs(self, cameras: Sequence[str]) -> dict[str, object]:
        """What the cameras' images depend on beyond the scenario.

        Retrained splat models (or a new ground-truth world) make new runs.
        """
        inputs: dict[str, object] = {}
        if "splat" in cameras:
            inputs["splat"] = repr(self._finished("splat"))
        truth = truth_world_path(self.ws.root)
        if "truth" in cameras and truth.is_file():
            inputs["truth"] = file_fingerprint(truth)
        return inputs

    def _dataset_info(self) -> Any:
        path = dataset_paths(self.ws.dataset_dir).dataset_json
        if not path.is_file():
            msg = f"{self.ws.root} has no dataset; the extract step must run first"
            raise StageError(msg)
        return DatasetInfo.load(path)

    def _cameras(self) -> tuple[CameraName, ...]:
        if self.options.cameras is not None:
            return self.options.cameras
        models = self.ws.splat_files.models_dir
        has_splat = models.is_dir() and any(models.glob("chunk_*.pt"))
        return ("raster", "splat") if has_splat else ("raster",)

    def _drive_cameras(self) -> tuple[CameraName, ...]:
        """The replay cameras, after the truth camera when there is a ground-truth world."""
        cams = self._cameras()
        if self.options.cameras is None and truth_world_path(self.ws.root).is_file():
            return ("truth", *(c for c in cams if c != "truth"))
        return cams

    # -- steps ------------------------------------------------------------------------------
    def extract(self, step: _Step) -> None:
        if self._imported():
            step.up_to_date = True
            step.message = "imported with cam2sim import (run it again to change the dataset)"
            return
        self._recorded("extract", lambda: extract(self.ws, progress=self.progress), step)

    def _imported(self) -> bool:
        """Whether the dataset came from ``cam2sim import`` (images, no bag to extract)."""
        record = self.ws.stage_record("extract")
        path = dataset_paths(self.ws.dataset_dir).dataset_json
        if record is None or record.state != "done" or not path.is_file():
            return False
        return bool(DatasetInfo.load(path).kind == "images")

    def map(self, step: _Step) -> None:

        osm = self.options.osm
        if osm is not None and not osm.is_file():
            msg = (
                f"OSM file {osm} does not exist; pass an existing .osm or .osm.pbf file with "
                "--osm, or leave --osm out to download the area from the Overpass API"
            )
            raise StageError(msg)
        opts = MapOptions(osm=osm)
        self._recorded(
            "map", lambda: build_map(self.ws, options=opts, progress=self.progress), step
        )

    def detect(self, step: _Step) -> None:
        info = self._dataset_info()
        if info.counts.lidar_scans == 0 and self.options.detect_model is None:
            msg = "no LiDAR scans and no camera detector (pass --detect-model to detect in images)"
            raise _NotApplicableError(msg)
        opts = DetectOptions(model=self.options.detect_model)
        self._recorded(
            "detect", lambda: run_detect(self.ws, options=opts, progress=self.progress), step
        )

    def scenario(self, step: _Step) -> None:
        self._recorded("scenario", lambda: run_scenario(self.ws, progress=self.progress), step)

    def _require_motion(self, what: str) -> None:
        """Raise not-applicable when the recorded car stood still (``what`` needs motion)."""
        path = self.ws.scenario_path
        if not path.is_file():
            return  # the step itself says what is missing
        length = stood_still_m(Scenario.load(path))
        if length is not None:
            msg = f"the car stood still ({length:.1f} m driven); {what}"
            raise _NotApplicableError(msg)

    def _require_intrinsics(self) -> None:
        """Fail before a long splat when the replay and drive steps could not render anyway."""
        if not (self.options.wants("replay") or self.options.wants("drive")):
            return
        path = dataset_paths(self.ws.dataset_dir).calibration_json
        if path.is_file() and Calibration.load(path).camera is None:
            msg = (
                "the recording has no camera intrinsics, which the replay and drive steps "
                f"need; {NO_INTRINSICS_HINT} (or --skip replay,drive to train the splat alone)"
            )
            raise StageError(msg)

    def splat(self, step: _Step) -> None:
        self._require_motion("a splat needs views from a moving camera")
        self._require_intrinsics()
        opts = self.options.splat
        if opts is None:
            import torch  # noqa: PLC0415

            cuda = torch.cuda.is_available()
            if not cuda and not self.options.splat_on_cpu:
                msg = "no CUDA GPU, and splat training on the CPU is turned off"
                raise _NotApplicableError(msg)
            lidar = self._dataset_info().counts.lidar_scans > 0
            opts = SplatStageOptions.for_run(
                cuda=cuda, lidar=lidar, bundle_adjust=self.options.bundle_adjust
            )
            if not cuda:
                step.message = "no CUDA GPU: trained the CPU preset"
        results: list[SplatResult] = []
        self._recorded(
            "splat",
            lambda: results.append(run_splat(self.ws, options=opts, progress=self.progress)),
            step,
        )
        if results:
            summary = _splat_summary(results[0])
            step.message = "; ".join(m for m in (step.message, summary) if m)

    def _steering_signal(self) -> str | None:
        if self.options.steering_signal is not None:
            return self.options.steering_signal
        names = [n for n, c in self._dataset_info().counts.signals.items() if c > 0]
        if "steering" in names:
            return "steering"
        return next((n for n in names if "steer" in n.lower()), None)

    def ads(self, step: _Step) -> None:
        from cam2sim.ads.train_options import TrainOptions  # noqa: PLC0415 -- lazy: imports cv2

        if self.options.policy is not None:
            msg = f"a policy was given ({self.options.policy}); no model is trained"
            raise _NotApplicableError(msg)
        self._require_motion("DAVE-2 learns steering from a drive")
        signal = self._steering_signal()
        derived = ""
        if signal is None:
            if not dataset_paths(self.ws.dataset_dir).trajectory_csv.is_file():
                msg = (
                    "the recording has no steering signal and no poses to derive one from (name "
                    "a signal 'steering' in config.yaml)"
                )
                raise _NotApplicableError(msg)
            signal = derive_steering(self.ws)
            derived = " (steering derived from the poses: the recording has none)"
        opts = (
            TrainOptions.same_street(signal)
            if self.options.ads is None
            else dataclasses.replace(self.options.ads, signal=signal)
        )
        self._recorded(
            TRAIN_STAGE, lambda: train_ads(self.ws, options=opts, progress=self.progress), step
        )
        onnx = self.ws.ads_files.onnx
        if step.up_to_date and onnx.is_file():
            step.message = derived.strip(" ()")
            return
        step.up_to_date = False
        step.message = f"wrote {export_ads(self.ws, progress=self.progress).path}{derived}"

    def _policy(self) -> str:
        """The given policy, else the trained DAVE-2 (unless ``--skip ads``), else pure pursuit.

        A run of some steps only (``--steps drive``) drives the DAVE-2 the workspace has.
        """
        if self.options.policy is not None:
            return self.options.policy
        onnx = self.ws.ads_files.onnx
        return str(onnx) if onnx.is_file() and "ads" not in self.options.skip else "pure-pursuit"

    def replay(self, step: _Step) -> None:
        cameras = self._cameras()
        every = self.options.replay_every
        note = ""
        if every is None:
            from cam2sim.splat.raster import has_cuda  # noqa: PLC0415 -- lazy: imports torch

            samples = len(Scenario.load(self.ws.scenario_path).trajectory.frame)
            cuda = "splat" not in cameras or has_cuda()
            every = replay_stride(samples, cameras, cuda=cuda)
            if every > 1:
                note = (
                    f" (every {every}th of {samples} frames: the splat renders on the CPU here; "
                    "--replay-every 1 for all)"
                )
        opts = ReplayOptions(cameras=cameras, frames=(None, None, every))
        inputs = hash_inputs(
            {
                "scenario": self.ws.done_inputs_hash("scenario"),
                "options": repr(opts),
                **self._camera_inputs(opts.cameras),
            }
        )
        runs = self._runs_current("replay", inputs)
        if runs is not None:
            step.up_to_date = True
            step.message = runs[0] + note
            return
        started = dt.datetime.now(dt.UTC)
        result = replay(self.ws, options=opts, progress=self.progress)
        self.ws.record_stage(
            "replay", state="done", started=started, inputs_hash=inputs, runs=(result.run_id,)
        )
        step.message = result.run_id + note

    def _judge(self) -> Literal["map", "truth"]:
        if self.options.judge is not None:
            return self.options.judge
        return default_judge(self.ws)

    def _drive_jobs(self, cameras: Sequence[CameraName]) -> list[DriveOptions]:
        """One job a closed-loop run of ``cameras`` (camera and seed, in that order).

        The seeded runs do not depend on each other. The first run of each camera keeps its
        frames for the report (unless all do).
        """
        policy = self._policy()
        recorded_speed, _ = self._recorded_speed()
        keep_first = self.options.report_frames
        return [
            DriveOptions(
                policy=policy,
                camera=cam,
                runs=1,
                seed=self.options.run_seed + r,
                steering_noise_std=self.options.steering_noise_std,
                variation=self.options.run_variation,
                recorded_speed=recorded_speed,
                judge=self._judge(),
                save_frames=self.options.save_frames or (keep_first and r == 0),
            )
            for cam in cameras
            for r in range(self.options.runs)
        ]

    def _drive_inputs(self, jobs: Sequence[DriveOptions]) -> str:
        """What ``jobs``' runs depend on: a new digest makes new runs."""
        model = Path(self._policy())
        cameras = tuple(dict.fromkeys(j.camera for j in jobs))
        return hash_inputs(
            {
                "scenario": self.ws.done_inputs_hash("scenario"),
                "options": [repr(j) for j in jobs],
                # A retrained model at the same path makes new runs.
                "model": file_fingerprint(model) if model.is_file() else None,
                **self._camera_inputs(cameras),
            }
        )

    def _drive_runs(self, jobs: Sequence[DriveOptions]) -> list[str]:
        """Drive ``jobs`` (in processes where the CPUs allow); their run ids in the jobs' order."""
        workers = self.options.drive_workers or default_drive_workers(len(jobs))
        if workers > 1 and len(jobs) > 1:
            return _drives_in_processes(self.ws.root, jobs, workers, self.progress)
        return [
            r.run_id for opts in jobs for r in drive(self.ws, options=opts, progress=self.progress)
        ]

    def _early_cameras(self) -> tuple[CameraName, ...]:
        """The drive cameras that need no splat: their runs can go while the splat trains."""
        return tuple(c for c in self._drive_cameras() if c in EARLY_CAMERAS)

    def drive_early(self) -> str:
        """Drive the runs of :meth:`_early_cameras` (beside the splat): what was driven.

        Recorded as :data:`EARLY_DRIVES` (inputs and run ids), where the drive step takes them
        from when its own jobs for those cameras are the same.
        """
        jobs = self._drive_jobs(self._early_cameras())
        if not jobs:
            return ""
        inputs = self._drive_inputs(jobs)
        if self._runs_current(EARLY_DRIVES, inputs) is None:
            started = dt.datetime.now(dt.UTC)
            runs = self._drive_runs(jobs)
            self.ws.record_stage(
                EARLY_DRIVES, state="done", started=started, inputs_hash=inputs, runs=tuple(runs)
            )
        cams = ", ".join(dict.fromkeys(j.camera for j in jobs))
        return f"{len(jobs)} run(s) of {cams} driven beside the splat"

    def drive(self, step: _Step) -> None:
        self._require_motion("closed-loop drives follow the recorded route")
        policy = self._policy()
        _, speed_note = self._recorded_speed()
        jobs = self._drive_jobs(self._drive_cameras())
        inputs = self._drive_inputs(jobs)
        runs = self._runs_current("drive", inputs)
        if runs is None:
            started = dt.datetime.now(dt.UTC)
            early = [j for j in jobs if j.camera in EARLY_CAMERAS]
            made = self._runs_current(EARLY_DRIVES, self._drive_inputs(early)) if early else None
            if made is None or len(made) != len(early):
                runs = self._drive_runs(jobs)
            else:  # the early cameras' runs were driven beside the splat: the rest now
                rest = iter(self._drive_runs([j for j in jobs if j.camera not in EARLY_CAMERAS]))
                done = iter(made)
                runs = [next(done) if j.camera in EARLY_CAMERAS else next(rest) for j in jobs]
            self.ws.record_stage(
                "drive", state="done", started=started, inputs_hash=inputs, runs=tuple(runs)
            )
        else:
            step.up_to_date = True
        cams = ", ".join(self._drive_cameras())
        step.message = f"{len(runs)} run(s), policy {policy}, camera {cams}{speed_note}"

    def _recorded_speed(self) -> tuple[bool, str]:
        """Whether the drives follow the recorded speed, and what the step's message says."""
        from cam2sim.sim.speed import SpeedProfile  # noqa: PLC0415

        if self.options.recorded_speed is not None:
            return self.options.recorded_speed, ""
        sc = Scenario.load(self.ws.scenario_path)
        tr = sc.trajectory
        profile = SpeedProfile.recorded(tr.center, tr.speed, tr.t)
        if not profile.changes_speed(sc.hero_start.speed):
            return False, ""
        slow, fast = profile.span_kmh()
        note = (
            f"; at the recorded speed, {slow:.0f}-{fast:.0f} km/h along the route "
            "(the recording changes speed; --start-speed holds its start speed)"
        )
        return True, note

    def evaluate(self, step: _Step) -> None:
        self._require_motion("there are no drives to score")
        runs = self._made_runs("drive")
        if not runs:
            msg = "no drive runs to evaluate; the drive step must run first"
            raise StageError(msg)
        opts = EvaluateOptions(
            drive_runs=tuple(runs),
            replay_runs=tuple(self._made_runs("replay")),
            real=self.options.real,
            real_crs=self.options.real_crs,
        )
        results: list[EvaluateResult] = []
        self._recorded(
            EVALUATE_STAGE,
            lambda: results.append(
                evaluate_workspace(self.ws, options=opts, progress=self.progress)
            ),
            step,
        )
        step.message = "; ".join([str(results[0].metrics), *results[0].notes])

    def report_step(self, step: _Step) -> None:
        from cam2sim.report.html import write_report  # noqa: PLC0415 -- lazy: imports matplotlib

        self.report = write_report(self.ws)
        step.message = str(self.report)


def run_pipeline(
    ws: Workspace,
    *,
    options: PipelineOptions | None = None,
    progress: ProgressCallback | None = None,
) -> PipelineResult:
    """Run every selected step in order; up-to-date steps skip, so a re-run resumes.

    A failing step is recorded ``failed`` with its message; the steps after it are ``skipped``
    unless ``options.continue_on_error``. An interruption (``KeyboardInterrupt``) propagates and
    leaves the finished steps in place for the next run.

    Args:
        ws: The workspace (created by ``cam2sim init``).
        options: Steps and their options; defaults run everything.
        progress: Receives a ``pipeline`` task (steps done of all) and each stage's tasks.
    """
    opts = options or PipelineOptions()
    report = serialized(progress or no_progress)  # DAVE-2 may report from beside the splat
    pipe = _Pipeline(ws, opts, report)
    handlers = _handlers(pipe)
    outcomes: list[StepOutcome] = []
    stopped: str | None = None
    beside: Sidecar | None = None
    side: tuple[str, ...] = BESIDE_SPLAT_STEPS if _ads_beside_splat(opts) else ()

    def finish(outcome: StepOutcome) -> None:
        nonlocal stopped
        outcomes.append(outcome)
        if not opts.wants(outcome.name):
            return
        logger.info("step %s: %s", outcome.name, outcome.state)
        pipe.record(outcome)
        if outcome.state == "failed" and not opts.continue_on_error:
            stopped = stopped or outcome.name

    try:
        for i, name in enumerate(STEPS):
            report("pipeline", i, len(STEPS))
            if name in side:  # run in the process beside the splat; outcomes at the last
                if name == side[0] and stopped is None:
                    beside = Sidecar(
                        _beside_splat,
                        (str(ws.root), opts),
                        progress=report,
                        name="ads",
                        cpus=_ads_beside_cpus(),
                        daemon=False,  # its drives may run in processes of their own
                    )
                if name == side[-1]:
                    if beside is None:  # a step before them failed: they never started
                        joined = tuple(_skipped(n, opts, stopped) for n in side)
                    else:
                        joined, beside = _joined(beside, side, opts), None
                    for outcome in joined:
                        finish(outcome)
            elif not opts.wants(name) or stopped is not None:
                finish(_skipped(name, opts, stopped))
            else:
                finish(_run_step(name, handlers[name]))
    finally:
        if beside is not None:  # interrupted (or failed) before the ads step joined it
            beside.stop()
    report("pipeline", len(STEPS), len(STEPS))
    ordered = sorted(outcomes, key=lambda o: STEPS.index(o.name))
    return PipelineResult(tuple(ordered), pipe.report)


def _skipped(name: str, opts: PipelineOptions, stopped: str | None) -> StepOutcome:
    """A step not run: not selected, or after a failed one."""
    why = "not selected" if not opts.wants(name) else f"{stopped} failed"
    return StepOutcome(name, "skipped", 0.0, why)


def _handlers(pipe: _Pipeline) -> dict[str, Callable[[_Step], None]]:
    return {
        "extract": pipe.extract,
        "map": pipe.map,
        "detect": pipe.detect,
        "scenario": pipe.scenario,
        "splat": pipe.splat,
        "ads": pipe.ads,
        "replay": pipe.replay,
        "drive": pipe.drive,
        "evaluate": pipe.evaluate,
        "report": pipe.report_step,
    }


def _ads_beside_splat(opts: PipelineOptions) -> bool:
    """Whether the ads step runs in its own process while the splat step runs."""
    if not (opts.wants("splat") and opts.wants("ads")) or opts.policy is not None:
        return False
    if opts.ads_beside_splat is not None:
        return opts.ads_beside_splat
    from cam2sim.splat.raster import has_cuda  # noqa: PLC0415 -- lazy: imports torch

    return available_cpus() >= BESIDE_MIN_CPUS and has_cuda()


def _ads_beside_cpus() -> int | None:
    """CPU threads of the ads step beside the splat (None: this process's).

    All but :data:`BESIDE_SPLAT_CPUS`; below :data:`BESIDE_MIN_CPUS` (where only the option put
    it beside) this process's.
    """
    cpus = available_cpus()
    return cpus - BESIDE_SPLAT_CPUS if cpus >= BESIDE_MIN_CPUS else None


def _beside_splat(
    root: str, options: PipelineOptions, *, progress: ProgressCallback
) -> tuple[StepOutcome, ...]:
    """The :data:`BESIDE_SPLAT_STEPS` of the workspace at ``root`` in a :class:`Sidecar` process.

    Detect and scenario (the splat reads neither: 8 s of Munich route 1's world on a GPU
    machine, before the splat started), then the ads step and, if the drive step is wanted, the
    runs of the cameras that need no splat (:meth:`_Pipeline.drive_early`): on a GPU machine
    they took 20-30 s of a world after the splat (nine runs, four processes) while DAVE-2 had
    finished minutes before it. Where those fail, the drive step drives them. A failed step
    skips the ones after it here as in the main process (unless ``continue_on_error``).
    """
    from cam2sim.core.workspace import Workspace  # noqa: PLC0415

    pipe = _Pipeline(Workspace.open(Path(root)), options, progress)
    handlers = _handlers(pipe)
    outcomes: list[StepOutcome] = []
    stopped: str | None = None
    for name in BESIDE_SPLAT_STEPS:
        if not options.wants(name) or stopped is not None:
            outcomes.append(_skipped(name, options, stopped))
            continue
        outcome = _run_step(name, handlers[name])
        if name == "ads" and outcome.state in {"done", "up_to_date"} and options.wants("drive"):
            outcome = _with_early_drives(pipe, outcome)
        outcomes.append(outcome)
        if outcome.state == "failed" and not options.continue_on_error:
            stopped = name
    return tuple(outcomes)


def _with_early_drives(pipe: _Pipeline, outcome: StepOutcome) -> StepOutcome:
    """The ads step's ``outcome`` after the runs that need no splat drove (or not: logged)."""
    try:
        note = pipe.drive_early()
    except Exception as err:  # noqa: BLE001 -- the drive step drives them after the splat
        logger.warning("the runs beside the splat were not driven (%s); the drive step will", err)
        return outcome
    return dataclasses.replace(outcome, message="; ".join(m for m in (outcome.message, note) if m))


def _joined(
    beside: Sidecar, steps: tuple[str, ...], opts: PipelineOptions
) -> tuple[StepOutcome, ...]:
    """The outcomes of the ``steps`` that ran beside the splat (seconds: their own wall time)."""
    try:
        outcomes: tuple[StepOutcome, ...] = beside.result()
    except StageError as err:  # the process itself failed (its steps' errors are outcomes)
        why = f"the process beside the splat failed: {err}"
        return tuple(
            StepOutcome(name, "failed", 0.0, why)
            if opts.wants(name)
            else _skipped(name, opts, None)
            for name in steps
        )
    notes = {"ads": "trained beside the splat"}
    return tuple(
        dataclasses.replace(
            o,
            message="; ".join(
                m for m in (o.message, notes.get(o.name, "ran beside the splat")) if m
            ),
        )
        if o.state == "done"
        else o
        for o in outcomes
    )


RUN_INPUTS: Final = "run_inputs.json"
"""``WS/run_inputs.json``: the inputs ``cam2sim run`` was last given (``--osm``, the detector)."""


def remember_inputs(ws: Workspace, options: PipelineOptions) -> PipelineOptions:
    """``options`` with the inputs an earlier run was given where this one gives none.

    A resume needs no repeat of ``--osm``, ``--detect-model``, ``--real`` or
    ``--bundle-adjust``: what a run is given is saved in ``WS/run_inputs.json`` and taken again
    by the next run that omits it (logged). A run that gives one again replaces it.
    """
    import json  # noqa: PLC0415
    import os  # noqa: PLC0415

    path = ws.root / RUN_INPUTS
    saved: dict[str, str] = {}
    if path.is_file():
        try:
            loaded = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            loaded = {}
        if isinstance(loaded, dict):
            saved = {k: v for k, v in loaded.items() if isinstance(v, str)}
    given = {
        "osm": options.osm,
        "detect_model": options.detect_model,
        "real": os.pathsep.join(str(p) for p in options.real) or None,
        "bundle_adjust": None if options.bundle_adjust is None else str(options.bundle_adjust),
    }
    used: dict[str, Any] = {}
    for key, value in given.items():
        if value is not None:
            saved[key] = str(value)
        elif key in saved:
            logger.info("run: using %s %s from the last run", key, saved[key])
        else:
            continue
        text = saved[key]
        if key == "osm":
            used[key] = Path(text)
        elif key == "real":
            used[key] = tuple(Path(p) for p in text.split(os.pathsep))
        elif key == "bundle_adjust":
            used[key] = text == "True"
        else:
            used[key] = text
    if saved:
        write_text_atomic(path, json.dumps(saved, indent=2) + "\n")
    return dataclasses.replace(options, **used)


def default_drive_workers(jobs: int) -> int:
    """Processes for the drive step's ``jobs`` runs: one a run where there are 4 CPUs a run.

    On a laptop's few cores the runs share them anyway (one process, no start-up cost); on a
    GPU machine the truth, splat and raster runs of every seed go side by side: one after
    another they took 66-127 s of a GPU benchmark world, each run 20-25 s (issue 37). The CPUs
    are the ones this process may use (a Ray task's share, else the machine's).
    """
    return max(1, min(jobs, available_cpus() // 4))


def _drive_camera(root: str, options: DriveOptions) -> list[str]:
    """One job's runs (a camera, one seed or several) in a worker process; their run ids."""
    from cam2sim.core.workspace import Workspace  # noqa: PLC0415

    return [r.run_id for r in drive(Workspace.open(Path(root)), options=options)]


def _drives_in_processes(
    root: Path, all_opts: Sequence[DriveOptions], workers: int, report: ProgressCallback
) -> list[str]:
    """Every job's runs, ``workers`` jobs at a time; run ids in the jobs' order.

    Each process gets its share of this one's CPUs (its thread pools sized to it): beside the
    splat's chunk workers (:func:`_beside_splat`) a pool of a process's every CPU in
    each run would contend with them.
    """
    import multiprocessing  # noqa: PLC0415
    from concurrent.futures import ProcessPoolExecutor  # noqa: PLC0415

    context = multiprocessing.get_context("spawn")
    share = max(1, available_cpus() // workers)
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        with children_allotted(share):  # the workers start at the submits
            futures = [pool.submit(_drive_camera, str(root), opts) for opts in all_opts]
        done: list[list[str]] = []
        for k, future in enumerate(futures):
            done.append(future.result())
            report("drive runs", k + 1, len(futures))
    return [run for runs in done for run in runs]


def _run_step(name: str, handler: Callable[[_Step], None]) -> StepOutcome:
    step = _Step()
    started = time.perf_counter()
    try:
        handler(step)
    except _NotApplicableError as err:
        return StepOutcome(name, "not_applicable", time.perf_counter() - started, str(err))
    except Exception as err:  # noqa: BLE001 - every step failure is recorded, not raised
        seconds = time.perf_counter() - started
        text = str(err) or type(err).__name__
        return StepOutcome(name, "failed", seconds, text)
    state: StepState = "up_to_date" if step.up_to_date else "done"
    return StepOutcome(name, state, time.perf_counter() - started, step.message)
