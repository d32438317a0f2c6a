"""Figures of a drive evaluation: trajectories in the corridor, lateral offset and steering."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.core.plots import pyplot as _pyplot
from cam2sim.core.plots import save_figure as _save
from cam2sim.metrics.behaviour import METHOD_COLOURS, METHOD_LABELS

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.metrics.drive_quality import DriveEvaluation

__all__ = ["write_drive_figures"]


def _label(run: Any) -> str:
    """The paper's name of a run's method: Real (recorded or in the truth world), splat, Sim."""
    return "Real" if run.real else METHOD_LABELS.get(run.method, run.method)


def _colours(ev: DriveEvaluation) -> dict[str, Any]:
    """One colour per method label: the paper's three fixed, any other from tab10."""
    plt = _pyplot()
    labels = list(dict.fromkeys(_label(r) for r in ev.runs))
    cmap = plt.get_cmap("tab10")
    others = [lb for lb in labels if lb not in METHOD_COLOURS]
    return {lb: METHOD_COLOURS.get(lb) or cmap(others.index(lb) % 10) for lb in labels}


def _trajectories(ev: DriveEvaluation, path: Path) -> None:
    plt = _pyplot()
    colours = _colours(ev)
    ok = np.isfinite(ev.corridor_min)
    c = ev.corridor_s[ok]
    centre = ev.reference.point_at(c)
    normal = ev.reference.normal_at(c)
    left = centre + normal * ev.corridor_max[ok, None]
    right = centre + normal * ev.corridor_min[ok, None]
    fig, ax = plt.subplots(figsize=(9, 7))
    band = np.vstack([left, right[::-1]])
    ax.fill(band[:, 0], band[:, 1], color="tab:green", alpha=0.25, lw=0, label="real corridor")
    seen: set[str] = set()
    for run in ev.runs:
        label = _label(run)
        colour = colours[label]
        ax.plot(
            run.xy[:, 0],
            run.xy[:, 1],
            color=colour,
            lw=0.8 if run.real else 1.2,
            label=None if label in seen else label,
        )
        seen.add(label)
    metrics = {r.name: r for r in ev.metrics.runs}
    for run in ev.runs:
        m = metrics.get(run.name)
        if m is not None and m.failure and m.failure != "invalid":
            ax.plot(*run.xy[-1], marker="x", color="red", ms=9, mew=2)
    seg = ev.metrics.segment
    ends = ev.reference.point_at(np.array([seg.start_m, seg.end_m]))
    ax.plot(*ends[0], marker="o", color="green", ms=8, label="segment start")
    ax.plot(*ends[1], marker="s", color="black", ms=8, label="segment end")
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(f"Runs in the real-drive corridor (segment {seg.length_m:.1f} m)")
    ax.legend(loc="best", fontsize=8)
    _save(fig, path)


def _lateral(ev: DriveEvaluation, path: Path) -> None:
    plt = _pyplot()
    colours = _colours(ev)
    fig, ax = plt.subplots(figsize=(10, 4))
    s0 = ev.metrics.segment.start_m
    seen: set[str] = set()
    ax.fill_between(
        ev.corridor_s - s0,
        ev.corridor_min,
        ev.corridor_max,
        color="tab:green",
        alpha=0.25,
        label="real corridor",
    )
    for run in ev.runs:
        lat = ev.lateral.get(run.name)
        if lat is None:
            continue
        label = _label(run)
        ax.plot(
            ev.corridor_s - s0, lat, color=colours[label], lw=0.8,
            label=None if label in seen else label,
        )  # fmt: skip
        seen.add(label)
    ax.set_xlabel("progress along the segment (m)")
    ax.set_ylabel("lateral offset (m), + = left of the path")
    ax.set_title("Lateral offset from the reference path, every run")
    _legend_below(ax)
    _save(fig, path)


def _legend_below(ax: Any) -> None:
    """One legend entry per method, below the axes, so no curve is hidden behind it."""
    ax.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)


def _steering(ev: DriveEvaluation, path: Path) -> None:
    plt = _pyplot()
    colours = _colours(ev)
    fig, ax = plt.subplots(figsize=(10, 4))
    s0 = ev.metrics.segment.start_m
    seen: set[str] = set()
    for run in ev.runs:
        if run.steering_t.size == 0:
            continue
        s = np.interp(np.clip(run.steering_t, run.t[0], run.t[-1]), run.t, ev.progress[run.name])
        label = _label(run)
        ax.plot(
            s - s0, run.steering, color=colours[label], lw=0.8,
            label=None if label in seen else label,
        )  # fmt: skip
        seen.add(label)
    ax.set_xlim(0, ev.metrics.segment.length_m)
    ax.set_xlabel("progress along the segment (m)")
    ax.set_ylabel("steering command (model units), + = left")
    ax.set_title("Steering against progress, every run")
    _legend_below(ax)
    _save(fig, path)


def write_drive_figures(ev: DriveEvaluation, out_dir: Path) -> list[Path]:
    """Write ``trajectories.png``, ``lateral_offset.png`` and ``steering.png``; return paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "trajectories.png", out_dir / "lateral_offset.png", out_dir / "steering.png"]
    _trajectories(ev, paths[0])
    _lateral(ev, paths[1])
    _steering(ev, paths[2])
    return paths
