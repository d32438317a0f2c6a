"""Drive quality: how close simulated driving comes to the real drives.

Definitions are in ``docs/metrics.md``. In short: the longest real run, resampled every 0.5 m,
is the reference path; every run is projected onto it with a monotone alignment; the scenario
segment is where all real runs overlap; the corridor is the envelope of the real runs' signed
lateral offsets (a single drive's envelope has no width: ``DriveOptions.single_drive_half_width_m``
gives it one); each simulated run gets completion, Min-Frechet against the real runs, corridor
violation and excess, steering jitter and a computed failure type.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt
import pydantic

from cam2sim.core import frames
from cam2sim.core.errors import StageError
from cam2sim.core.polyline import (
    ReferencePath,
    arc_length,
    resample_by_arc_length,
    resample_indices,
)
from cam2sim.core.schema import Artifact
from cam2sim.metrics.drive_io import DriveRun, runs_in_frame
from cam2sim.metrics.frechet import discrete_frechet
from cam2sim.metrics.splat_gate import MethodGate

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    "DriveEvaluation",
    "DriveMetrics",
    "DriveOptions",
    "MethodSummary",
    "RunMetrics",
    "Segment",
    "evaluate_drives",
    "steering_jitter",
]

logger = logging.getLogger(__name__)

TERMINAL_EVENTS = ("collision", "off_road", "stuck", "timeout")


@dataclass(frozen=True)
class DriveOptions:
    """Parameters of the drive metrics (defaults reproduce the published definitions)."""

    reference_spacing_m: float = 0.5
    corridor_spacing_m: float = 0.5
    projection_spacing_m: float = 0.25
    max_lateral_m: float = 4.0
    success_threshold: float = 0.95
    frechet_spacing_m: float = 0.5
    frechet_points: int | None = None
    jitter_min_dt_s: float = 0.05
    jitter_max_dt_s: float = 0.25
    straight_curvature_per_m: float = 0.005
    min_samples: int = 10
    single_drive_half_width_m: float | None = None
    """Half-width of a corridor that one real drive gives (its envelope has no width): that
    drive's line +- this, metres. None keeps the published envelope (zero width). The evaluate
    stage sets it to the lane's margin, (lane width - car width) / 2: inside it the car's
    footprint stays in the recorded lane."""

    def __post_init__(self) -> None:
        h = self.single_drive_half_width_m
        if h is not None and not (np.isfinite(h) and 0.0 <= h <= self.max_lateral_m):
            msg = (
                f"single_drive_half_width_m={h!r}; give 0 to {self.max_lateral_m} metres "
                "(or None for the published zero-width corridor of one drive)"
            )
            raise ValueError(msg)


class Segment(Artifact):
    """The scenario segment: the reference path and the stretch all real runs cover."""

    reference_run: str
    proj_string: str | None
    origin_lat_deg: float | None = None
    origin_lon_deg: float | None = None
    reference_length_m: float
    start_m: float
    end_m: float
    length_m: float
    spacing_m: float
    path_x: list[float]
    path_y: list[float]
    path_s: list[float]

    def reference_path(self) -> ReferencePath:
        """The reference polyline of this segment."""
        return ReferencePath(
            xy=np.stack([self.path_x, self.path_y], -1),
            s=np.asarray(self.path_s),
            spacing_m=self.spacing_m,
        )


class RunMetrics(pydantic.BaseModel):
    """Metrics of one run (metres and steering units per second; None where undefined)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    name: str
    method: str
    real: bool
    points: int
    completion: float
    success: bool
    min_frechet_m: float | None = None
    min_frechet_vs: str | None = None
    twin_frechet_m: float | None = pydantic.Field(
        None,
        description=(
            "Fréchet distance to the closed-loop real run of the same seed (its twin: the same "
            "drawn start and speed, only the camera differs); None for real runs and runs "
            "without a twin"
        ),
    )
    twin: str | None = None
    corridor_violation_pct: float | None = None
    mean_excess_m: float | None = None
    mean_excess_when_out_m: float | None = None
    jitter: float | None = None
    max_jitter: float | None = None
    jitter_samples: int = 0
    failure: (
        Literal["collision", "off_road", "stuck", "timeout", "incomplete", "invalid"] | None
    ) = None
    steering_error: Literal["oversteer", "understeer"] | None = None
    left_corridor_at_m: float | None = None
    notes: list[str] = pydantic.Field(default_factory=list)


class MethodSummary(pydantic.BaseModel):
    """Per-method aggregates; averages over successful runs (jitter over all runs)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    method: str
    runs: int
    successes: int
    failure_rate: float
    completion_mean: float
    completion_min: float
    completion_max: float
    avg_min_frechet_m: float | None
    avg_twin_frechet_m: float | None = None
    avg_corridor_violation_pct: float | None
    avg_mean_excess_m: float | None
    avg_mean_excess_when_out_m: float | None
    avg_jitter: float | None
    max_jitter: float | None
    failure_types: dict[str, int]


class DriveMetrics(Artifact):
    """``metrics.json`` of ``cam2sim evaluate drive``."""

    segment: Segment
    corridor_mean_width_m: float
    corridor_max_width_m: float
    corridor_samples: int
    corridor_rule: str = pydantic.Field(
        "envelope",
        description=(
            "How the corridor was made: 'envelope' of the real runs' lateral offsets, or "
            "'single drive +- H m' where one real drive gave it"
        ),
    )
    runs: list[RunMetrics]
    methods: list[MethodSummary]
    options: dict[str, float | int | None]
    splat_gate: list[MethodGate] = pydantic.Field(
        default_factory=list,
        description="The splat quality gate per method whose runs recorded splat quality",
    )


@dataclass(frozen=True)
class _Projected:
    run: DriveRun
    s: npt.NDArray[np.float64]  # progress at every point of the run
    on_route: npt.NDArray[np.bool_]
    lateral_c: npt.NDArray[np.float64]  # signed lateral at corridor samples (NaN outside)
    max_progress: float


@dataclass(frozen=True)
class DriveEvaluation:
    """Everything computed, for reports and figures."""

    metrics: DriveMetrics
    reference: ReferencePath
    corridor_s: npt.NDArray[np.float64]
    corridor_min: npt.NDArray[np.float64]
    corridor_max: npt.NDArray[np.float64]
    runs: list[DriveRun]
    lateral: dict[str, npt.NDArray[np.float64]] = field(default_factory=dict)
    progress: dict[str, npt.NDArray[np.float64]] = field(default_factory=dict)


def _valid(run: DriveRun) -> str | None:
    if len(run) < 2:
        return f"{len(run)} point(s); a run needs at least 2"
    if not (np.isfinite(run.xy).all() and np.isfinite(run.t).all()):
        return "NaN or infinite positions or times"
    if arc_length(run.xy)[-1] <= 0:
        return "the vehicle never moved"
    return None


def _project(
    run: DriveRun, ref: ReferencePath, c: npt.NDArray[np.float64], opts: DriveOptions
) -> _Projected:
    idx = resample_indices(run.xy, opts.projection_spacing_m)
    proj = ref.project(run.xy[idx], max_lateral_m=opts.max_lateral_m)
    s_all = np.interp(np.arange(len(run)), idx, proj.progress_m)
    on_all = np.interp(np.arange(len(run)), idx, proj.on_route.astype(float)) > 0.5
    keep = proj.on_route & (
        proj.progress_m > np.maximum.accumulate(np.r_[-np.inf, proj.progress_m[:-1]])
    )
    lateral_c = np.full(c.shape, np.nan)
    if keep.sum() >= 2:
        sk, lk = proj.progress_m[keep], proj.lateral_m[keep]
        inside = (c >= sk[0]) & (c <= sk[-1])
        lateral_c[inside] = np.interp(c[inside], sk, lk)
    on_s = proj.progress_m[proj.on_route]
    return _Projected(run, s_all, on_all, lateral_c, float(on_s.max()) if on_s.size else 0.0)


def steering_jitter(
    t: npt.NDArray[np.float64],
    value: npt.NDArray[np.float64],
    *,
    fixed_dt: float | None = None,
    min_dt: float = 0.05,
    max_dt: float = 0.25,
) -> tuple[float | None, float | None, int]:
    """Std and max of the steering rate (units/s) between consecutive decisions.

    Rates come from true time differences, keeping pairs with ``min_dt < dt <= max_dt``; with
    ``fixed_dt`` every consecutive pair uses that interval instead.

    Returns:
        (std, max |rate|, number of rates); (None, None, 0) when there are no rates.
    """
    if t.shape[0] < 2:
        return None, None, 0
    dv = np.diff(value)
    if fixed_dt is not None:
        rate = dv / fixed_dt
    else:
        dt = np.diff(t)
        ok = (dt > min_dt) & (dt <= max_dt)
        rate = dv[ok] / dt[ok]
    if rate.size == 0:
        return None, None, 0
    return float(np.std(rate)), float(np.max(np.abs(rate))), int(rate.size)


def _frechet(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], opts: DriveOptions) -> float:
    def prep(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        if opts.frechet_points:
            n = min(opts.frechet_points, xy.shape[0])
            picked: npt.NDArray[np.float64] = xy[np.linspace(0, xy.shape[0] - 1, n).astype(int)]
            return picked
        return resample_by_arc_length(xy, opts.frechet_spacing_m)

    return discrete_frechet(prep(a), prep(b))


def _segment_points(p: _Projected, start: float, end: float) -> npt.NDArray[np.float64]:
    """The run's polyline between progress ``start`` and ``end``, cut at exactly those points.

    Cutting at the interpolated crossing (not at the first sample inside) makes two runs'
    resampled vertices line up along the route, so near-identical runs score near zero.
    """
    s, xy = p.s, p.run.xy
    inside = np.flatnonzero((s >= start) & (s <= end))
    if inside.size == 0:
        return xy[:0]
    pieces = []
    first, last = int(inside[0]), int(inside[-1])
    if first > 0 and s[first] > start > s[first - 1]:
        f = (start - s[first - 1]) / (s[first] - s[first - 1])
        pieces.append(xy[first - 1] + f * (xy[first] - xy[first - 1]))
    pieces.extend(xy[first : last + 1])
    if last + 1 < s.shape[0] and s[last] < end < s[last + 1]:
        f = (end - s[last]) / (s[last + 1] - s[last])
        pieces.append(xy[last] + f * (xy[last + 1] - xy[last]))
    return np.asarray(pieces, dtype=np.float64).reshape(-1, 2)


def _excess(
    lateral: npt.NDArray[np.float64], cmin: npt.NDArray[np.float64], cmax: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    return np.where(lateral < cmin, cmin - lateral, np.where(lateral > cmax, lateral - cmax, 0.0))


@dataclass(frozen=True)
class _Corridor:
    c: npt.NDArray[np.float64]
    cmin: npt.NDArray[np.float64]
    cmax: npt.NDArray[np.float64]


def _corridor(
    lateral: list[npt.NDArray[np.float64]],
    c: npt.NDArray[np.float64],
    single_half_width_m: float | None = None,
) -> _Corridor:
    """The envelope of the real runs' lateral offsets; one run's line +- the given half-width."""
    stack = np.vstack(lateral)
    valid = np.isfinite(stack).any(axis=0)
    cmin = np.full(c.shape, np.nan)
    cmax = np.full(c.shape, np.nan)
    cmin[valid] = np.nanmin(stack[:, valid], axis=0)
    cmax[valid] = np.nanmax(stack[:, valid], axis=0)
    if single_half_width_m is not None and stack.shape[0] == 1:
        cmin -= single_half_width_m
        cmax += single_half_width_m
    return _Corridor(c, cmin, cmax)


def _steering_error(
    p: _Projected, corridor: _Corridor, ref: ReferencePath, opts: DriveOptions
) -> tuple[str | None, float | None]:
    """Where the run last left the corridor and which way relative to the curve."""
    lat = p.lateral_c
    valid = np.isfinite(lat) & np.isfinite(corridor.cmin)
    if not valid.any():
        return None, None
    idx = np.flatnonzero(valid)
    out = _excess(lat[idx], corridor.cmin[idx], corridor.cmax[idx]) > 0
    if not out[-1]:
        return None, None
    inside = np.flatnonzero(~out)
    first_out = idx[inside[-1] + 1] if inside.size else idx[0]
    s_exit = float(corridor.c[first_out])
    side = 1.0 if lat[first_out] > corridor.cmax[first_out] else -1.0
    kappa = ref.curvature()
    window = (ref.s >= s_exit - 5.0) & (ref.s <= s_exit + 15.0)
    k = float(np.mean(kappa[window])) if window.any() else 0.0
    if abs(k) < opts.straight_curvature_per_m:
        return None, s_exit
    return ("oversteer" if np.sign(k) == side else "understeer"), s_exit


def _completion(p: _Projected, seg: Segment) -> float:
    """Share of the scenario segment the run drove (0 to 1)."""
    return float(np.clip((p.max_progress - seg.start_m) / seg.length_m, 0.0, 1.0))


def _pair_frechet(
    p: _Projected,
    o: _Projected,
    mine: npt.NDArray[np.float64],
    seg: Segment,
    opts: DriveOptions,
    cache: dict[tuple[str, str], float],
) -> float | None:
    """Fréchet distance of ``p`` (its segment points ``mine``) and ``o``, or None.

    None where either has fewer than two points in the segment.
    Two runs that both completed are compared up to where the first stopped: a simulated run
    ends within the route's end tolerance, a recorded drive at its last pose, and the metres
    between are no difference in driving.
    """
    end = seg.end_m
    both = _completion(p, seg) >= opts.success_threshold
    if both and _completion(o, seg) >= opts.success_threshold:
        end = min(end, p.max_progress, o.max_progress)
    theirs = _segment_points(o, seg.start_m, end)
    mine_cut = mine if end >= seg.end_m else _segment_points(p, seg.start_m, end)
    if theirs.shape[0] < 2 or mine_cut.shape[0] < 2:
        return None
    key = (min(p.run.name, o.run.name), max(p.run.name, o.run.name))
    if key not in cache:
        cache[key] = _frechet(mine_cut, theirs, opts)
    return cache[key]


def _twin(p: _Projected, real: Sequence[_Projected]) -> _Projected | None:
    """The closed-loop real run of ``p``'s seed (the same drawn start), if there is one."""
    if p.run.real or p.run.seed is None:
        return None
    return next((o for o in real if o.run.seed == p.run.seed), None)


def _run_metrics(
    p: _Projected,
    others: Sequence[_Projected],
    corridor: _Corridor,
    seg: Segment,
    ref: ReferencePath,
    opts: DriveOptions,
    cache: dict[tuple[str, str], float],
    twin: _Projected | None = None,
) -> RunMetrics:
    run = p.run
    completion = _completion(p, seg)
    success = completion >= opts.success_threshold
    notes: list[str] = []
    mine = _segment_points(p, seg.start_m, seg.end_m)
    best, best_vs = None, None
    if mine.shape[0] >= 2:
        for o in others:
            d = _pair_frechet(p, o, mine, seg, opts, cache)
            if d is not None and (best is None or d < best):
                best, best_vs = d, o.run.name
    else:
        notes.append("never inside the scenario segment")
    twin_d = None
    if twin is not None and mine.shape[0] >= 2:
        twin_d = _pair_frechet(p, twin, mine, seg, opts, cache)
    viol = mean_ex = when_out = None
    valid = np.isfinite(p.lateral_c) & np.isfinite(corridor.cmin)
    if valid.sum() >= opts.min_samples:
        ex = _excess(p.lateral_c[valid], corridor.cmin[valid], corridor.cmax[valid])
        viol = float(100.0 * np.mean(ex > 0))
        mean_ex = float(np.mean(ex))
        when_out = float(np.mean(ex[ex > 0])) if (ex > 0).any() else 0.0
    else:
        notes.append(f"only {int(valid.sum())} corridor samples; corridor metrics undefined")
    st = np.clip(run.steering_t, run.t[0], run.t[-1])
    s_steer = np.interp(st, run.t, p.s)
    in_seg = (s_steer >= seg.start_m) & (s_steer <= seg.end_m) & (run.steering_t >= run.t[0])
    in_seg &= run.steering_t <= run.t[-1]
    jit, jmax, jn = steering_jitter(
        run.steering_t[in_seg],
        run.steering[in_seg],
        fixed_dt=run.steering_dt,
        min_dt=opts.jitter_min_dt_s,
        max_dt=opts.jitter_max_dt_s,
    )
    failure: str | None = None
    steer_err: str | None = None
    left_at: float | None = None
    if not run.real and not success:
        terminal = sorted((e for e in run.events if e.kind in TERMINAL_EVENTS), key=lambda e: e.t)
        failure = terminal[0].kind if terminal else "incomplete"
        steer_err, left_at = _steering_error(p, corridor, ref, opts)
    return RunMetrics(
        name=run.name,
        method=run.method,
        real=run.real,
        points=len(run),
        completion=completion,
        success=success,
        min_frechet_m=best,
        min_frechet_vs=best_vs,
        twin_frechet_m=twin_d,
        twin=None if twin_d is None or twin is None else twin.run.name,
        corridor_violation_pct=viol,
        mean_excess_m=mean_ex,
        mean_excess_when_out_m=when_out,
        jitter=jit,
        max_jitter=jmax,
        jitter_samples=jn,
        failure=failure,
        steering_error=steer_err,
        left_corridor_at_m=left_at,
        notes=notes,
    )


def _mean(values: list[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def _summaries(runs: list[RunMetrics]) -> list[MethodSummary]:
    out = []
    for method in dict.fromkeys(r.method for r in runs):
        group = [r for r in runs if r.method == method]
        ok = [r for r in group if r.success]
        comp = [r.completion for r in group]
        types = {
            "out_of_road": sum(r.failure == "off_road" for r in group),
            "collision": sum(r.failure == "collision" for r in group),
            "oversteer": sum(r.steering_error == "oversteer" for r in group),
            "understeer": sum(r.steering_error == "understeer" for r in group),
        }
        maxima = [r.max_jitter for r in group if r.max_jitter is not None]
        out.append(
            MethodSummary(
                method=method,
                runs=len(group),
                successes=len(ok),
                failure_rate=1.0 - len(ok) / len(group),
                completion_mean=float(np.mean(comp)),
                completion_min=float(np.min(comp)),
                completion_max=float(np.max(comp)),
                avg_min_frechet_m=_mean([r.min_frechet_m for r in ok]),
                avg_twin_frechet_m=_mean([r.twin_frechet_m for r in ok]),
                avg_corridor_violation_pct=_mean([r.corridor_violation_pct for r in ok]),
                avg_mean_excess_m=_mean([r.mean_excess_m for r in ok]),
                avg_mean_excess_when_out_m=_mean([r.mean_excess_when_out_m for r in ok]),
                avg_jitter=_mean([r.jitter for r in group]),
                max_jitter=max(maxima) if maxima else None,
                failure_types=types,
            )
        )
    return out


def _frame_for(runs: list[DriveRun], segment: Segment | None) -> frames.WorldFrame | None:
    if (
        segment is not None
        and segment.origin_lat_deg is not None
        and segment.origin_lon_deg is not None
    ):
        return frames.WorldFrame(segment.origin_lat_deg, segment.origin_lon_deg)
    crss = {r.crs for r in runs}
    if None in crss:
        if len(crss) > 1:
            msg = "some runs are geo-referenced and some are not; they cannot be compared"
            raise StageError(msg)
        return None
    first = runs[0]
    return frames.WorldFrame.at_crs_point(
        first.crs or "", float(first.xy[0, 0]), float(first.xy[0, 1])
    )


def _make_segment(
    real: list[_Projected], ref: ReferencePath, name: str, world: frames.WorldFrame | None
) -> Segment:
    starts, ends = [], []
    for p in real:
        on = p.s[p.on_route]
        if on.size < 2:
            msg = f"real run {p.run.name} never follows the reference path; check the inputs"
            raise StageError(msg)
        starts.append(float(on[0]))
        ends.append(float(np.maximum.accumulate(on)[-1]))
    start, end = max(starts), min(ends)
    if end <= start:
        msg = "the real runs do not overlap along the route; they cannot define a segment"
        raise StageError(msg)
    return Segment(
        reference_run=name,
        proj_string=world.proj_string if world else None,
        origin_lat_deg=world.origin_lat_deg if world else None,
        origin_lon_deg=world.origin_lon_deg if world else None,
        reference_length_m=ref.length_m,
        start_m=start,
        end_m=end,
        length_m=end - start,
        spacing_m=ref.spacing_m,
        path_x=ref.xy[:, 0].tolist(),
        path_y=ref.xy[:, 1].tolist(),
        path_s=ref.s.tolist(),
    )


def evaluate_drives(
    real: list[DriveRun],
    sim: list[DriveRun],
    *,
    segment: Segment | None = None,
    options: DriveOptions | None = None,
) -> DriveEvaluation:
    """Score simulated runs (and each real run, leave-one-out) against the real drives.

    Raises:
        StageError: No valid real run, or the real runs do not overlap.
    """
    opts = options or DriveOptions()
    bad_real = [(r.name, why) for r in real if (why := _valid(r))]
    if bad_real:
        msg = "; ".join(f"real run {n}: {why}" for n, why in bad_real)
        raise StageError(msg + "; fix or remove these runs")
    if not real:
        msg = "no real runs given; pass --real with the recorded trajectories"
        raise StageError(msg)
    world = _frame_for(real, segment)
    if world is not None:
        real = runs_in_frame(real, world)
    invalid = {r.name: why for r in sim if (why := _valid(r))}
    good_sim = [r for r in sim if r.name not in invalid]
    if world is not None and good_sim:
        good_sim = runs_in_frame(good_sim, world)
    if segment is None:
        longest = max(real, key=lambda r: arc_length(r.xy)[-1])
        ref = ReferencePath.from_polyline(longest.xy, spacing_m=opts.reference_spacing_m)
        probe = [_project(r, ref, np.zeros(0), opts) for r in real]
        segment = _make_segment(probe, ref, longest.name, world)
    ref = segment.reference_path()
    c = np.arange(segment.start_m, segment.end_m, opts.corridor_spacing_m)
    real_p = [_project(r, ref, c, opts) for r in real]
    sim_p = [_project(r, ref, c, opts) for r in good_sim]
    half = opts.single_drive_half_width_m
    corridor = _corridor([p.lateral_c for p in real_p], c, half)
    results: list[RunMetrics] = []
    cache: dict[tuple[str, str], float] = {}
    for i, p in enumerate(real_p):
        others = [o for j, o in enumerate(real_p) if j != i]
        loo = _corridor([o.lateral_c for o in others], c, half) if others else corridor
        results.append(_run_metrics(p, others, loo, segment, ref, opts, cache))
    results += [
        _run_metrics(p, real_p, corridor, segment, ref, opts, cache, _twin(p, real_p))
        for p in sim_p
    ]
    results += [
        RunMetrics(
            name=r.name,
            method=r.method,
            real=False,
            points=len(r),
            completion=0.0,
            success=False,
            failure="invalid",
            notes=[why],
        )
        for r in sim
        if (why := invalid.get(r.name))
    ]
    width = corridor.cmax - corridor.cmin
    metrics = DriveMetrics(
        segment=segment,
        corridor_mean_width_m=float(np.nanmean(width)) if np.isfinite(width).any() else 0.0,
        corridor_max_width_m=float(np.nanmax(width)) if np.isfinite(width).any() else 0.0,
        corridor_samples=int(np.isfinite(width).sum()),
        corridor_rule=(
            f"single drive +- {half:.2f} m" if half is not None and len(real_p) == 1 else "envelope"
        ),
        runs=results,
        methods=_summaries(results),
        options=dict(vars(opts)),
    )
    all_p = real_p + sim_p
    return DriveEvaluation(
        metrics=metrics,
        reference=ref,
        corridor_s=c,
        corridor_min=corridor.cmin,
        corridor_max=corridor.cmax,
        runs=[p.run for p in all_p],
        lateral={p.run.name: p.lateral_c for p in all_p},
        progress={p.run.name: p.s for p in all_p},
    )
