"""A campaign's report: ``CAMPAIGN/report.html``, one self-contained page.

What a campaign writes to ``summary.json`` (:mod:`cam2sim.campaign.summary`), shown as people
read it: the time and throughput, one table row per recording, policy and camera with the
route-completion rate and its 95 % interval (Wilson), one plot panel per recording (each run's
completion and the completion rate of each policy and camera), the runs each host and GPU did,
and every run that did not finish with its log. It reads the summary's rows as plain mappings,
so it can be rendered again from ``summary.json`` alone (:func:`report_from_summary`).
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import PurePath
from typing import TYPE_CHECKING, Any

from cam2sim import __version__
from cam2sim.core.files import write_text_atomic
from cam2sim.core.plots import pyplot
from cam2sim.metrics.benchmark import wilson_interval
from cam2sim.report.pieces import esc, fmt, html_table, png_img

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence
    from pathlib import Path

__all__ = ["REPORT_FILE", "report_from_summary", "short_names", "write_campaign_report"]

REPORT_FILE = "report.html"

_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:3px 8px;
text-align:right}th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}
caption{text-align:left;font-weight:600;padding:.3em 0}img{max-width:100%}
.note{color:#555;font-size:.9em}
"""

_MAX_PANELS = 24
"""Recordings drawn in the plot (the table lists them all)."""


def _label(row: Mapping[str, Any]) -> str:
    return f"{row['policy']} / {row['camera']}"


def _rate(row: Mapping[str, Any]) -> tuple[str, str]:
    """Routes completed of the finished runs, and the 95 % interval of that rate."""
    done, ok = int(row["done"]), int(row["successes"])
    if done == 0:
        return "-", "-"
    low, high = wilson_interval(ok, done)
    return f"{ok}/{done}", f"{100 * low:.0f}-{100 * high:.0f} %"


def short_names(names: Iterable[str]) -> dict[str, str]:
    """Each recording's name without the folders all of them share.

    ``/tmp/bench/worlds/a/ws`` and ``/tmp/bench/worlds/b/ws`` become ``a/ws`` and ``b/ws``: the
    table and the panels show what tells the recordings apart. One recording keeps its name.
    """
    unique = list(dict.fromkeys(names))
    parts = [PurePath(n).parts for n in unique]
    shared = 0
    while len(unique) > 1 and all(
        len(p) > shared + 1 and p[shared] == parts[0][shared] for p in parts
    ):
        shared += 1
    return {n: str(PurePath(*p[shared:])) for n, p in zip(unique, parts, strict=True)}


def _summary_table(summary: Sequence[Mapping[str, Any]], names: Mapping[str, str]) -> str:
    rows = []
    for s in summary:
        rate, interval = _rate(s)
        rows.append(
            [
                names[s["workspace"]], s["policy"], s["camera"], s["runs"], s["done"], s["failed"],
                rate, interval, fmt(s["completion_mean"]), fmt(s["min_frechet_mean_m"]),
                fmt(s["corridor_violation_mean_pct"], ".1f"),
            ]
        )  # fmt: skip
    headers = [
        "recording", "policy", "camera", "runs", "finished", "failed", "route completed",
        "95 % interval", "completion (mean)", "Min-Fréchet (m)", "corridor violations (%)",
    ]  # fmt: skip
    return html_table(headers, rows, "Per recording, policy and camera")


def _panels(
    summary: Sequence[Mapping[str, Any]],
    runs: Sequence[Mapping[str, Any]],
    names: Mapping[str, str],
) -> Any:
    """One panel per recording: each run's completion (dots), the completion rate (bars)."""
    plt = pyplot()
    worlds = list(dict.fromkeys(s["workspace"] for s in summary))[:_MAX_PANELS]
    cols = min(3, max(1, len(worlds)))
    nrows = -(-len(worlds) // cols)
    fig, axes = plt.subplots(
        nrows, cols, figsize=(4.2 * cols, 3.0 * nrows), squeeze=False, sharey=True
    )
    for ax in axes.flat[len(worlds) :]:
        ax.axis("off")
    for ax, world in zip(axes.flat, worlds, strict=False):
        groups = [s for s in summary if s["workspace"] == world]
        for x, s in enumerate(groups):
            done, ok = int(s["done"]), int(s["successes"])
            if done:
                low, high = wilson_interval(ok, done)
                ax.bar(x, ok / done, color="#cfe0f0", width=0.6)
                ax.errorbar(x, ok / done, yerr=[[ok / done - low], [high - ok / done]],
                            color="#446", capsize=3, lw=1)  # fmt: skip
            values = [
                r["completion"]
                for r in runs
                if r["workspace"] == world
                and _label(r) == _label(s)
                and r["completion"] is not None
            ]
            if values:
                n = len(values)
                spread = [x + 0.3 * ((i + 0.5) / n - 0.5) for i in range(n)]
                ax.plot(spread, values, "o", color="#c44", ms=4)
            elif not done:
                ax.text(x, 0.5, "no run finished", rotation=90, ha="center", va="center",
                        color="#777", fontsize=8)  # fmt: skip
        ax.set_xticks(range(len(groups)), [_label(s) for s in groups], rotation=20, ha="right")
        ax.set_xlim(-0.6, len(groups) - 0.4)
        ax.set_ylim(0, 1.05)
        ax.set_title(names[world], fontsize=10)
    axes[0][0].set_ylabel("completion (dots); completed (bars)")
    fig.tight_layout()
    return fig


def _places(runs: Sequence[Mapping[str, Any]]) -> str:
    """Runs per host and GPU (what each did), when more than one place ran them."""
    by: dict[str, list[float]] = {}
    for r in runs:
        if r.get("place") and r["status"] != "missing":
            by.setdefault(str(r["place"]), []).append(float(r["seconds"] or 0.0))
    if len(by) < 2 and not any(" GPU " in p for p in by):
        return ""
    rows = [
        [place, len(times), fmt(sum(times), ".0f"), fmt(sum(times) / len(times), ".1f")]
        for place, times in sorted(by.items())
    ]
    headers = ["where (host, GPU)", "runs", "run seconds", "seconds a run"]
    return html_table(headers, rows, "Where the runs ran (their latest attempts)")


def _not_finished(runs: Sequence[Mapping[str, Any]], folder: Path, names: Mapping[str, str]) -> str:
    rows = [
        [r["spec_id"], names[r["workspace"]], _label(r), r["seed"], r["status"],
         str((folder / "logs" / f"{r['spec_id']}.log").relative_to(folder))]
        for r in runs
        if r["status"] != "done"
    ]  # fmt: skip
    if not rows:
        return '<p class="note">Every run finished.</p>'
    headers = ["run", "recording", "policy / camera", "seed", "status", "log"]
    return html_table(headers, rows, "Runs that did not finish")


def write_campaign_report(
    folder: Path,
    summary: Sequence[Mapping[str, Any]],
    runs: Sequence[Mapping[str, Any]],
    *,
    name: str,
    seconds: float | None = None,
    ran: int | None = None,
) -> Path:
    """Write ``folder/report.html`` from the summary's rows; its path.

    Args:
        folder: The campaign folder.
        summary: ``summary.json``'s ``summary`` rows.
        runs: Its ``runs`` rows.
        name: The campaign's name (the title).
        seconds: Wall time of this invocation's runs, for the throughput line.
        ran: Runs this invocation ran.
    """
    finished = sum(r["status"] == "done" for r in runs)
    names = short_names([*(s["workspace"] for s in summary), *(r["workspace"] for r in runs)])
    lines = [f"{len(runs)} runs in the plan, {finished} finished"]
    if seconds and ran:
        lines.append(
            f"this invocation ran {ran} in {seconds:.0f} s ({60 * ran / seconds:.1f} runs/min)"
        )
    parts = [
        f"<h1>Campaign {esc(name)}</h1>",
        f"<p>{esc('; '.join(lines))}.</p>",
        _summary_table(summary, names),
        (
            '<p class="note">Route completed: finished runs that completed the route, with the '
            "95 % Wilson interval of that rate. Min-Fréchet and corridor: means over the runs "
            "that completed, against the recorded drive (docs/metrics.md).</p>"
        ),
    ]
    if summary:
        parts.append(png_img(_panels(summary, runs, names), alt="completion per recording"))
    parts.append(_places(runs))
    parts.append(_not_finished(runs, folder, names))
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(f'<p class="note">cam2sim {esc(__version__)}, {stamp}</p>')
    page = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(name)}</title>"
        f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>\n"
    )
    path = folder / REPORT_FILE
    write_text_atomic(path, page)
    return path


def report_from_summary(folder: Path, *, name: str | None = None) -> Path:
    """Render ``folder/report.html`` again from ``folder/summary.json``."""
    body = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    return write_campaign_report(folder, body["summary"], body["runs"], name=name or folder.name)
