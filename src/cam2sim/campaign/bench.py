"""``cam2sim bench``: the paper's experiment on every world of a suite, and the figures across.

Each world of the suite (:mod:`cam2sim.campaign.suite`) is one campaign job: the whole
experiment of ``cam2sim demo`` (recording, map, detect, scenario, splat, DAVE-2, replay, the
Real / splat / Sim drives, evaluation) in ``BENCH/worlds/<label>/``, then its figures in
``result.json`` (:class:`~cam2sim.metrics.benchmark.WorldResult`): the behaviour per method,
the splat's quality, the splat against the truth every 10 m along the route (on the path and
1 m to each side) and, for every failed run, the views of the splat, the truth and the
simulator camera at the pose just before the failure.

Jobs run through the campaign's executors: a local process pool (one world at a time by
default: a world already uses every core) or Ray with one GPU per world (its splat) on a cluster
with GPUs. ``BENCH/state.json`` records every world's outcome, so a second ``cam2sim bench`` on
the same folder runs only the worlds without a result (and those that failed); a world
interrupted half way resumes inside its own pipeline (its stages skip when up to date). At the
end :func:`write_bench_report` writes the report (``report.html``, ``summary.md``,
``tables/*.csv``, ``aggregate.json``) from every world that has a result.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cam2sim.campaign.executors import Job, LocalPool
from cam2sim.campaign.runner import campaign_lock
from cam2sim.campaign.state import CampaignState, RunOutcome
from cam2sim.campaign.suite import expand_suite, load_suite
from cam2sim.campaign.worker import run_logged
from cam2sim.core.errors import StageError
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.metrics.benchmark import FailureRow, MethodRow, WorldResult, aggregate

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from cam2sim.campaign.executors import Executor
    from cam2sim.campaign.suite import SuiteSettings, WorldSpec
    from cam2sim.core.workspace import RunPaths, Workspace
    from cam2sim.metrics.benchmark import Aggregate
    from cam2sim.metrics.drive_quality import DriveMetrics, RunMetrics
    from cam2sim.stages.experiment import Experiment
    from cam2sim.stages.splat import SplatStageOptions

__all__ = [
    "BenchResult",
    "bench_folder",
    "execute_world",
    "rescore_world",
    "run_bench",
    "splat_options",
    "world_result",
]

logger = logging.getLogger(__name__)
TASK = "benchmark worlds"
RESULT = "result.json"
FAILURE_CAMERAS = ("splat", "truth", "raster")
"""The views drawn at a failure: the splat, the ground truth (what Real saw) and Sim's."""
_BEFORE_FAILURE_S = 0.5
"""The failure views show the pose this long before the failure (the policy's last look)."""


@dataclass(frozen=True)
class BenchResult:
    """What a ``cam2sim bench`` invocation did.

    Attributes:
        folder: The benchmark folder.
        worlds: Worlds in the suite.
        ran: Worlds attempted now.
        failed: Worlds of this invocation that failed, timed out or crashed.
        seconds: Wall time of the worlds run now.
        results: Every world with a result (done now or before).
        aggregate: The figures across them.
        report: The HTML report.
    """

    folder: Path
    worlds: int
    ran: int
    failed: int
    seconds: float
    results: list[WorldResult]
    aggregate: Aggregate
    report: Path


def bench_folder(suite_path: Path, output: Path | None = None) -> Path:
    """The benchmark folder: ``output``, or ``SUITE_STEM-bench/`` beside the suite."""
    if output is not None:
        return Path(output).resolve()
    path = Path(suite_path).resolve()
    return path.parent / f"{path.stem}-bench"


def _world_dir(folder: Path, spec: WorldSpec) -> Path:
    return folder / "worlds" / spec.label


# -- one world --------------------------------------------------------------------------------


def _method_rows(ws: Workspace) -> tuple[list[MethodRow], DriveMetrics]:
    from cam2sim.metrics.behaviour import METHOD_LABELS  # noqa: PLC0415 -- lazy: numpy
    from cam2sim.metrics.drive_quality import DriveMetrics  # noqa: PLC0415 -- lazy: numpy

    path = ws.report_files.metrics_json
    if not path.is_file():
        msg = f"{ws.root} has no drive evaluation ({path}); its evaluate step did not run"
        raise StageError(msg)
    metrics = DriveMetrics.load(path)
    recorded = Counter(r.method for r in metrics.runs if r.name.endswith("/recorded"))
    rows = [
        MethodRow(
            method=METHOD_LABELS.get(m.method, m.method),
            runs=m.runs,
            failures=m.runs - m.successes,
            recorded=recorded.get(m.method, 0),
            completion_mean=m.completion_mean,
            min_frechet_m=m.avg_min_frechet_m,
            corridor_violation_pct=m.avg_corridor_violation_pct,
            jitter=m.avg_jitter,
            failure_types=dict(m.failure_types),
            min_frechet_runs_m=[
                r.min_frechet_m
                for r in metrics.runs
                if r.method == m.method and r.success and r.min_frechet_m is not None
            ],
            twin_frechet_runs_m=[
                r.twin_frechet_m
                for r in metrics.runs
                if r.method == m.method and r.success and r.twin_frechet_m is not None
            ],
        )
        for m in metrics.methods
    ]
    return rows, metrics


def _cause(files: RunPaths, run: RunMetrics) -> str:
    """What the run's events and metrics say about its failure, in one line."""
    from cam2sim.core.run_record import RunEvents  # noqa: PLC0415

    parts = []
    if files.events_json.is_file():
        ends = [e for e in RunEvents.load(files.events_json).events if e.kind != "route_completed"]
        parts += [f"{e.kind} at t={e.t:.1f} s: {e.reason}" if e.reason else e.kind for e in ends]
    if run.steering_error is not None:
        parts.append(f"steering: {run.steering_error}")
    if run.left_corridor_at_m is not None:
        parts.append(f"left the Real corridor at {run.left_corridor_at_m:.0f} m")
    parts += list(run.notes)
    return "; ".join(parts)


def _failures(ws: Workspace, metrics: DriveMetrics, labels: Mapping[str, str]) -> list[FailureRow]:
    """Every failed run with its cause and the views at its pose just before the failure."""
    import numpy as np  # noqa: PLC0415

    from cam2sim.core.workspace import run_paths  # noqa: PLC0415
    from cam2sim.stages.cameras import write_png  # noqa: PLC0415 -- lazy: cv2
    from cam2sim.stages.route_profile import failure_views  # noqa: PLC0415 -- lazy: torch

    rows: list[FailureRow] = []
    length = float(metrics.segment.reference_length_m)
    for run in metrics.runs:
        if run.success:
            continue
        run_id = run.name.split("/", 1)[-1]
        files = run_paths(ws.runs_dir / run_id)
        row = FailureRow(
            method=labels.get(run.method, run.method),
            run=run_id,
            kind=run.failure or "incomplete",
            reason=_cause(files, run),
        )
        if not files.trajectory_csv.is_file():
            rows.append(row)
            continue
        table = np.genfromtxt(files.trajectory_csv, delimiter=",", names=True)
        t = np.atleast_1d(table["t"])
        k = int(np.searchsorted(t, t[-1] - _BEFORE_FAILURE_S))
        xy = (float(np.atleast_1d(table["x"])[k]), float(np.atleast_1d(table["y"])[k]))
        heading = float(np.atleast_1d(table["heading"])[k])
        try:
            views = failure_views(ws, xy, heading, cameras=FAILURE_CAMERAS)
        except StageError as err:
            rows.append(row.model_copy(update={"reason": f"{row.reason}; no views: {err}"}))
            continue
        image = Path("failures") / f"{run_id}.png"
        write_png(ws.root.parent / image, views.image)
        rows.append(
            row.model_copy(
                update={
                    "s_m": round(views.s_m, 1),
                    "route_share": round(views.s_m / length, 3) if length else None,
                    "image": str(image),
                    "views": list(views.labels),
                    "views_psnr_db": [None if v is None else round(v, 2) for v in views.psnr_db],
                    "splat_psnr_on_path_db": views.psnr_db[0],
                }
            )
        )
    return rows


def _splat_facts(ws: Workspace) -> dict[str, object]:
    from cam2sim.splat.chunk_header import ChunkHeader  # noqa: PLC0415
    from cam2sim.splat.evaluate import SplatEval  # noqa: PLC0415
    from cam2sim.splat.train_options import TrainResult, chunk_result_path  # noqa: PLC0415

    facts: dict[str, object] = {}
    headers = sorted(ws.splat_files.models_dir.glob("chunk_*.json"))
    chunks = [ChunkHeader.load(h) for h in headers]
    facts["splat_steps"] = [c.steps for c in chunks]
    facts["splat_stopped"] = [str(c.stopped) for c in chunks]
    facts["splat_gaussians"] = [c.n_gaussians for c in chunks]
    results = [chunk_result_path(ws.splat_files.models_dir, c.chunk_id) for c in chunks]
    if all(r.is_file() for r in results):  # the starting counts are in the training results
        facts["splat_start_gaussians"] = [TrainResult.load(r).n_initial_gaussians for r in results]
    facts["splat_device"] = chunks[0].backend if chunks else None
    path = ws.splat_files.eval_json
    if path.is_file():
        ev = SplatEval.load(path)
        facts["splat_held_out_psnr_db"] = ev.psnr_db.mean
        facts["splat_held_out_ssim"] = ev.ssim.mean
        if ev.truth is not None:
            facts["splat_truth_psnr_db"] = {s.label(): s.psnr_db.mean for s in ev.truth.scores}
    return facts


def world_result(spec: WorldSpec, done: Experiment, seconds: float) -> WorldResult:
    """The figures of one finished world (see the module's description).

    Raises:
        StageError: The world's evaluation is missing (a step failed).
    """
    from cam2sim.metrics.behaviour import METHOD_LABELS  # noqa: PLC0415 -- lazy: numpy
    from cam2sim.stages.ads import ONNX_FILE  # noqa: PLC0415
    from cam2sim.stages.route_profile import route_profile  # noqa: PLC0415 -- lazy: torch

    ws = done.ws
    methods, metrics = _method_rows(ws)
    failures = _failures(ws, metrics, METHOD_LABELS)
    model = ws.ads_dir / ONNX_FILE  # the drives' DAVE-2: its steering on splat and truth views
    prof = route_profile(
        ws,
        every_m=spec.settings.profile_every_m,
        policy=str(model) if model.is_file() else None,
    ).to_json()
    steps = {o.name: round(o.seconds, 1) for o in done.result.outcomes if o.seconds}
    if done.built_s is not None:
        steps = {"recording": round(done.built_s, 1), **steps}
    if spec.builtin is not None:
        source = f"built-in street {spec.builtin}"
    elif spec.route is None:
        source = f"{spec.osm}, picked route {spec.pick}"
    else:
        source = f"{spec.osm}, route {spec.route[0]} to {spec.route[1]}"
    return WorldResult(
        label=spec.label,
        spec_id=spec.spec_id,
        run_seed=spec.run_seed,
        title=done.title,
        tuned=spec.tuned,
        source=source,
        notes=list(done.notes),
        route_m=float(metrics.segment.reference_length_m),
        seconds=round(seconds, 1),
        step_seconds=steps,
        methods=methods,
        failures=failures,
        profile=prof,
        **_splat_facts(ws),
    )


def rescore_world(world_dir: Path) -> WorldResult:
    """A finished world's result with its drives scored again by today's drive metrics.

    The drive runs in ``WORLD/ws`` are evaluated again (``ws/report/drive/metrics.json`` is
    rewritten) and the result's behaviour rows replaced; everything else the world measured
    (the splat, the profile, the failures' views, the times) is kept. For measures added after
    a world ran (the distance of each run to its Real twin), without running it again.

    Raises:
        StageError: The world has no result or no drive runs (it did not finish).
    """
    from cam2sim.core.workspace import Workspace  # noqa: PLC0415
    from cam2sim.stages.evaluate import drive_run_ids, evaluate_workspace_drives  # noqa: PLC0415

    path = Path(world_dir) / RESULT
    if not path.is_file():
        msg = f"{world_dir} has no {RESULT}; run the world with `cam2sim bench` first"
        raise StageError(msg)
    result = WorldResult.load(path)
    ws = Workspace.open(Path(world_dir) / "ws")
    runs = drive_run_ids(ws)
    if not runs:
        msg = f"{ws.root} has no drive runs to score again"
        raise StageError(msg)
    evaluate_workspace_drives(ws, runs, ws.drive_eval_dir)
    methods, _ = _method_rows(ws)
    return result.model_copy(update={"methods": methods})


def _run_world(spec: WorldSpec, out: Path) -> str:
    from cam2sim.stages.experiment import (  # noqa: PLC0415 -- lazy: numpy
        ExperimentOptions,
        WorldSource,
        run_experiment,
    )

    started = time.perf_counter()
    source = WorldSource(
        builtin=spec.builtin,
        osm=None if spec.osm_path is None else Path(spec.osm_path),
        route=spec.route,
        pick=spec.pick,
    )
    settings = spec.settings
    splat = None
    if any(
        v is not None
        for v in (settings.splat_steps, settings.splat_init_points, settings.splat_max_gaussians)
    ):
        import torch  # noqa: PLC0415

        splat = splat_options(settings, cuda=bool(torch.cuda.is_available()))
    # The workspace's own HTML report is left out: the benchmark's report is what is read, and
    # encoding the kept frames' videos took 30-45 s a world (`cam2sim report WS` writes it).
    # For the same reason DAVE-2 is not validated: the network that drives is the same one,
    # trained in about half the time (the demo's validated run is for its report).
    options = ExperimentOptions(
        runs=spec.seeds, run_seed=spec.run_seed, splat=splat, ads_epochs=settings.ads_epochs,
        save_frames=settings.save_frames, skip=("report",), ads_validate=False,
    )  # fmt: skip
    done = run_experiment(out, source, options)
    if done.result.failed:
        failed = [f"{o.name}: {o.message}" for o in done.result.outcomes if o.state == "failed"]
        raise StageError("a pipeline step failed: " + "; ".join(failed))
    result = world_result(spec, done, time.perf_counter() - started)
    result.save(out / RESULT)
    return spec.label


def splat_options(settings: SuiteSettings, *, cuda: bool) -> SplatStageOptions:
    """The demo's splat preset for the device (``cuda``) with the suite's splat settings.

    ``splat_steps``: that many steps a chunk, no plateau and no time budget;
    ``splat_init_points``: each chunk starts from about that many of its points, thinned with
    the distance from its cameras (``TrainOptions.max_init_points``);
    ``splat_max_gaussians``: no more growth of a chunk once it has that many Gaussians, pruning
    goes on (``DensifyOptions.max_gaussians``).
    """
    from cam2sim.stages.splat import SplatStageOptions  # noqa: PLC0415

    splat = SplatStageOptions.demo(cuda=cuda)
    assert splat.train is not None  # the preset sets it
    train = splat.train
    if settings.splat_steps is not None:  # a fixed step count instead of the preset's
        steps = settings.splat_steps
        train = dataclasses.replace(
            train, max_steps=steps, min_steps=steps, val_every=max(1, steps // 2),
            time_budget_s=None,
        )  # fmt: skip
    if settings.splat_init_points is not None:
        train = dataclasses.replace(train, max_init_points=settings.splat_init_points)
    if settings.splat_max_gaussians is not None:
        densify = dataclasses.replace(train.densify, max_gaussians=settings.splat_max_gaussians)
        train = dataclasses.replace(train, densify=densify)
    return dataclasses.replace(splat, train=train)


def execute_world(spec: WorldSpec, log_path: str, timeout_s: float | None) -> RunOutcome:
    """Run one world of a suite (in a worker process; never raises for a failed world)."""
    out = Path(log_path).parent.parent / "worlds" / spec.label
    what = f"world {spec.label} ({spec.builtin or spec.osm})"
    return run_logged(spec.spec_id, what, lambda: _run_world(spec, out), log_path, timeout_s)


# -- the suite --------------------------------------------------------------------------------


def _set_aside_stale(folder: Path, specs: Sequence[WorldSpec]) -> None:
    """Rename each result another version of its world made, so that the world runs again.

    A world's folder is named by its label; its ``result.json`` counts as done only when it
    was made by the same world (its ``spec_id``: route, seeds, settings). One made by another
    (the suite's settings or seeds changed since) becomes ``result.OTHER-HASH.json``, kept
    beside the new one. Results written before ids were recorded count as done, as before.
    """
    for spec in specs:
        path = _world_dir(folder, spec) / RESULT
        if not path.is_file():
            continue
        made_by = WorldResult.load(path).spec_id
        if made_by and made_by != spec.spec_id:
            kept = path.with_name(f"result.{made_by.rsplit('-', 1)[-1]}.json")
            path.replace(kept)
            logger.warning(
                "world %s: its result was made by another version of it (%s, not %s): kept as "
                "%s, the world runs again",
                spec.label, made_by, spec.spec_id, kept.name,
            )  # fmt: skip


def run_bench(
    suite_path: Path,
    *,
    output: Path | None = None,
    executor: Executor | None = None,
    retry_failed: bool = True,
    progress: ProgressCallback | None = None,
) -> BenchResult:
    """Run the suite's worlds that have no result yet, then write the report over all of them.

    Raises:
        ConfigError: The suite is invalid (the message names the key and the fix).
        WorkspaceError: Another ``cam2sim bench`` runs in the same folder.
    """
    suite_path = Path(suite_path)
    suite = load_suite(suite_path)
    specs = expand_suite(suite, suite_path.resolve().parent)
    folder = bench_folder(suite_path, output)
    folder.mkdir(parents=True, exist_ok=True)
    report = progress or no_progress
    with campaign_lock(folder):
        state_path = folder / "state.json"
        state = CampaignState.load_or_new(state_path, suite.name or suite_path.stem)
        _set_aside_stale(folder, specs)
        todo = [
            s
            for s in specs
            if not (_world_dir(folder, s) / RESULT).is_file()
            and (retry_failed or s.spec_id not in state.runs)
        ]
        by_id = {s.spec_id: s for s in todo}
        jobs = [Job(s, str(folder / "logs" / f"{s.label}.log"), suite.timeout_s) for s in todo]
        runner = executor or LocalPool(1, task=execute_world)
        logger.info("bench %s: %d of %d worlds to run on the %s", state.name, len(jobs),
                    len(specs), runner.name)  # fmt: skip
        finished: list[RunOutcome] = []

        def record(outcome: RunOutcome) -> None:
            nonlocal state
            state = state.with_outcome(outcome, by_id[outcome.spec_id].label)
            state.save(state_path)
            finished.append(outcome)
            if outcome.status != "done":
                logger.warning("world %s %s: %s (log: %s)", by_id[outcome.spec_id].label,
                               outcome.status, outcome.error, outcome.log)  # fmt: skip
            report(TASK, len(finished), len(jobs))

        started = time.perf_counter()
        report(TASK, 0, len(jobs))
        try:
            if jobs:
                runner.run(jobs, record)
        finally:
            state.save(state_path)
        seconds = time.perf_counter() - started
        results = [
            WorldResult.load(p) for s in specs if (p := _world_dir(folder, s) / RESULT).is_file()
        ]
        from cam2sim.report.bench import write_bench_report  # noqa: PLC0415 -- lazy: matplotlib

        agg = aggregate(results)
        missing = {
            s.label: (state.runs[s.spec_id].error or state.runs[s.spec_id].status)
            for s in specs
            if s.spec_id in state.runs and not (_world_dir(folder, s) / RESULT).is_file()
        }
        path = write_bench_report(folder, results, agg, missing=missing, name=state.name)
    return BenchResult(
        folder=folder,
        worlds=len(specs),
        ran=len(finished),
        failed=sum(o.status != "done" for o in finished),
        seconds=seconds,
        results=results,
        aggregate=agg,
        report=path,
    )
