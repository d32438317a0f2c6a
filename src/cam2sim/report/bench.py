"""The benchmark report: the suite's figures as one self-contained HTML page and tables.

:func:`write_bench_report` writes into the benchmark folder:

- ``report.html``: the verdict; the failure rate of each method with its 95 % Wilson interval
  (a plot and a table); the paired per-street table (splat against Real, Sim beside them), with
  and without the streets looked at while tuning; per street the behaviour table, the splat's
  quality and its PSNR against the truth along the route (a plot, failures marked); every
  failure with its cause and the splat / truth / Sim views at the pose before it;
- ``summary.md``: the same tables in Markdown;
- ``tables/rates.csv``, ``tables/streets.csv``, ``tables/methods.csv``, ``tables/failures.csv``;
- ``aggregate.json``: :class:`~cam2sim.metrics.benchmark.Aggregate`.

It only reads the worlds' ``result.json``; worlds without one are listed with why.
"""

from __future__ import annotations

import base64
import csv
import datetime as dt
import io
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cam2sim import __version__
from cam2sim.core.files import write_text_atomic
from cam2sim.core.plots import pyplot
from cam2sim.metrics.behaviour import METHOD_COLOURS
from cam2sim.metrics.benchmark import aggregate
from cam2sim.report.pieces import esc, fmt, html_table, png_img

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from cam2sim.metrics.benchmark import Aggregate, WorldResult

__all__ = [
    "bench_tables",
    "gap_figure",
    "gap_prediction",
    "rank_correlation",
    "rates_figure",
    "steering_gap_mean",
    "write_bench_report",
]

COLOURS = METHOD_COLOURS
_GLOSSARY = (
    "Real: the recorded drive plus DAVE-2's closed-loop runs in the ground-truth world (the "
    "truth camera); splat: DAVE-2 driving on the splat's images; Sim: on the simulator's raster "
    "images. Runs of each method differ by seed (start pose, speed, steering noise); the runs "
    "of one seed are the same draw for every method (each result.json names its first seed). "
    "A run's Min-Fréchet is its distance to the nearest Real run other than itself, so Real's "
    "is mostly the spread of the drawn starts; 'to Real twin' is a run's distance to the Real "
    "run of its own seed (the same start): what the camera alone changed."
)
_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em;display:block;max-width:100%;
overflow-x:auto}td,th{border:1px solid #ccc;padding:3px 8px;
text-align:right}th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}
caption{text-align:left;font-weight:600;padding:.3em 0}.verdict{font-size:1.2em;
font-weight:600;background:#f6f6e8;padding:.6em;border-left:4px solid #996}
img{max-width:100%}.note{color:#555;font-size:.9em}h3{margin-top:1.6em}
"""


def _markdown(headers: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + " --- |" * len(headers)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _file_img(path: Path, alt: str) -> str:
    """The image at ``path`` embedded as JPEG (failure views: a tenth of their PNG's size)."""
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
    ok, buf = (
        (False, None)
        if image is None
        else cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    )
    if not ok or buf is None:
        return f'<p class="note">({esc(alt)}: image missing)</p>'
    data = base64.b64encode(buf.tobytes()).decode("ascii")
    return f'<img alt="{esc(alt)}" src="data:image/jpeg;base64,{data}">'


# -- the tables (shared by HTML, Markdown and CSV) --------------------------------------------


def bench_tables(
    results: Sequence[WorldResult], agg: Aggregate
) -> dict[str, tuple[list[str], list[list[object]]]]:
    """The report's tables as ``name -> (headers, rows)``; the CSV files hold the same."""
    rates: tuple[list[str], list[list[object]]] = (
        ["method", "streets", "runs", "failures", "failure rate", "95% low", "95% high",
         "streets failing", "Min-Fréchet m", "corridor viol. %"],
        [
            [r.method, r.streets, r.runs, r.failures, fmt(r.rate, ".3f"), fmt(r.low, ".3f"),
             fmt(r.high, ".3f"), r.streets_failing, fmt(r.min_frechet_m),
             fmt(r.corridor_violation_pct, ".1f")]
            for r in agg.rates
        ],
    )  # fmt: skip
    streets: tuple[list[str], list[list[object]]] = (
        ["street", "tuned", "Real fail", "splat fail", "Sim fail", "splat-Real rate",
         "Fréchet splat/Real", "its 95% interval", "splat to Real twin m", "splat ~ Real",
         "Sim corridor excess %"],
        [
            [p.label, "yes" if p.tuned else "no", p.real_failures, p.splat_failures,
             p.sim_failures, fmt(p.failure_rate_diff, "+.2f"), fmt(p.frechet_ratio),
             "-" if p.frechet_ratio_low is None or p.frechet_ratio_high is None
             else f"{p.frechet_ratio_low:.2f}-{p.frechet_ratio_high:.2f}",
             fmt(p.splat_twin_frechet_m),
             {True: "yes", False: "NO", None: "-"}[p.splat_matches_real],
             fmt(p.sim_corridor_excess_pct, "+.1f")]
            for p in agg.pairs
        ],
    )  # fmt: skip
    methods: tuple[list[str], list[list[object]]] = (
        ["street", "method", "runs", "failures", "completion", "Min-Fréchet m",
         "to Real twin m", "corridor viol. %", "jitter", "failure types"],
        [
            [w.label, m.method, m.runs, m.failures, fmt(m.completion_mean, ".3f"),
             fmt(m.min_frechet_m),
             fmt(m.twin_frechet_m),
             fmt(m.corridor_violation_pct, ".1f"), fmt(m.jitter, ".3f"),
             ", ".join(f"{k} {v}" for k, v in sorted(m.failure_types.items())) or "-"]
            for w in results
            for m in w.methods
        ],
    )  # fmt: skip
    failures: tuple[list[str], list[list[object]]] = (
        ["street", "method", "run", "failure", "at m", "route share", "splat PSNR dB there",
         "reason"],
        [
            [w.label, f.method, f.run, f.kind, fmt(f.s_m, ".0f"), fmt(f.route_share, ".2f"),
             fmt(f.splat_psnr_on_path_db, ".1f"), f.reason or "-"]
            for w in results
            for f in w.failures
        ],
    )  # fmt: skip
    splat: tuple[list[str], list[list[object]]] = (
        ["street", "route m", "device", "steps a chunk", "stopped", "Gaussians a chunk k",
         "held-out PSNR",
         "held-out SSIM", "truth on path", "truth 1 m right", "truth 1 m left",
         "profile min PSNR", "mean steering gap", "largest steering gap (at m)",
         "steering gain splat/truth", "world s"],
        [
            [w.label, fmt(w.route_m, ".0f"), w.splat_device or "-",
             "/".join(str(s) for s in w.splat_steps) or "-",
             "/".join(sorted(set(w.splat_stopped))) or "-", _gaussians_text(w),
             fmt(w.splat_held_out_psnr_db, ".1f"), fmt(w.splat_held_out_ssim, ".3f"),
             fmt(w.splat_truth_psnr_db.get("on path"), ".1f"),
             fmt(_truth_at(w, "+1"), ".1f"), fmt(_truth_at(w, "-1"), ".1f"),
             fmt(_profile_min(w), ".1f"), fmt(steering_gap_mean(w), ".3f"), _gap_text(w),
             fmt(steering_gain(w), ".3f"),
             fmt(w.seconds, ".0f")]
            for w in results
        ],
    )  # fmt: skip
    return {
        "rates": rates,
        "streets": streets,
        "methods": methods,
        "splat": splat,
        "failures": failures,
    }


def _truth_at(world: WorldResult, offset: str) -> float | None:
    """The truth envelope's mean PSNR at a lateral offset (its labels: ``+1 m``, ``-0.5 m``)."""
    return world.splat_truth_psnr_db.get(f"{offset} m")


def _profile_min(world: WorldResult) -> float | None:
    values = [v for v in _on_path(world, "psnr_db") or [] if v is not None]
    return min(values) if values else None


def _on_path(world: WorldResult, key: str) -> list[float | None] | None:
    """Row ``key`` of the profile on the path (offset 0), or None."""
    if not world.profile or key not in world.profile:
        return None
    offsets = list(world.profile.get("offsets_m", []))  # type: ignore[call-overload]
    if 0.0 not in offsets:
        return None
    row: list[float | None] = world.profile[key][offsets.index(0.0)]  # type: ignore[index]
    return row


def steering_gap_peak(world: WorldResult) -> tuple[float, float] | None:
    """The largest |splat - truth| steering of the drives' policy on the path, and where (m)."""
    gaps = [(abs(b - a), s) for s, a, b in _steering_pairs(world)]
    return max(gaps) if gaps else None


def steering_gap_mean(world: WorldResult) -> float | None:
    """The mean |splat - truth| steering of the drives' policy over the path's stations.

    Measured on the splat alone (no drive): across the streets of 2026-12-07 it ordered the
    splat runs' Min-Fréchet almost exactly (docs/benchmarks.md, "The steering gap predicts the
    drive"), where the splat's PSNR did not.
    """
    pairs = _steering_pairs(world)
    return sum(abs(b - a) for _, a, b in pairs) / len(pairs) if pairs else None


def rank_correlation(x: Sequence[float], y: Sequence[float]) -> float | None:
    """Spearman's rank correlation of ``x`` and ``y`` (ties ranked by their mean), or None.

    None with fewer than three pairs or where either has no spread.
    """
    import numpy as np  # noqa: PLC0415

    if len(x) != len(y) or len(x) < 3:  # a rank order needs three
        return None

    def ranks(v: Sequence[float]) -> Any:
        a = np.asarray(v, dtype=np.float64)
        _, inverse, counts = np.unique(a, return_inverse=True, return_counts=True)
        ends = np.cumsum(counts)
        return ((ends - counts + ends - 1) / 2.0)[inverse]  # each tie gets the mean rank

    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return None
    return float(np.corrcoef(rx, ry)[0, 1])


def _gap_points(
    results: Sequence[WorldResult],
) -> list[tuple[str, float, float, float | None]]:
    """``(street, mean steering gap, splat Min-Fréchet m, splat to its twin m)`` per street."""
    points = []
    for w in results:
        gap, splat = steering_gap_mean(w), w.method("splat")
        if gap is None or splat is None or splat.min_frechet_m is None:
            continue
        points.append((w.label, gap, splat.min_frechet_m, splat.twin_frechet_m))
    return points


def gap_prediction(results: Sequence[WorldResult]) -> str | None:
    """One sentence: how well the steering gap orders the splat runs' Min-Fréchet, or None."""
    points = _gap_points(results)
    rho = rank_correlation([p[1] for p in points], [p[2] for p in points])
    if rho is None:
        return None
    return (
        f"The splat's steering gap (mean |splat - truth| steering of the drives' DAVE-2 on the "
        f"path's stations, measured without driving) against its runs' Min-Fréchet over "
        f"{len(points)} streets: Spearman rank correlation {rho:.2f}"
    )


def steering_gain(world: WorldResult) -> float | None:
    """How much harder the drives' policy steers on the splat view than on the truth's, on the path.

    The least-squares slope through the origin of its splat steering on its truth steering at
    the profile's stations: 1 is the same, 1.10 is 10 % harder (the bends weigh most, where it
    steers most). On Aguascalientes route 0 DAVE-2 steered 3 % harder on the GPU splat and 13 %
    on the CPU splat, in both of the route's bends (docs/benchmarks.md, "The GPU demo's preset
    on four untuned streets").
    """
    pairs = _steering_pairs(world)
    weight = sum(a * a for _, a, _ in pairs)
    return sum(a * b for _, a, b in pairs) / weight if weight > 0 else None


def _steering_pairs(world: WorldResult) -> list[tuple[float, float, float]]:
    """``(station m, truth steering, splat steering)`` on the path where both were asked."""
    truth, splat = _on_path(world, "steering_truth"), _on_path(world, "steering_splat")
    if truth is None or splat is None or not world.profile:
        return []
    stations: list[float] = world.profile["s_m"]  # type: ignore[assignment]
    return [
        (s, a, b)
        for s, a, b in zip(stations, truth, splat, strict=True)
        if a is not None and b is not None
    ]


def _gaussians_text(world: WorldResult) -> str:
    """Each chunk's street Gaussians in thousands, ``start-end`` where the start is known."""
    ends = world.splat_gaussians
    if not ends:
        return "-"
    starts = world.splat_start_gaussians
    if len(starts) != len(ends):
        return "/".join(f"{e / 1e3:.0f}" for e in ends)
    return "/".join(f"{s / 1e3:.0f}-{e / 1e3:.0f}" for s, e in zip(starts, ends, strict=True))


def _gap_text(world: WorldResult) -> str:
    peak = steering_gap_peak(world)
    return "-" if peak is None else f"{peak[0]:.2f} ({peak[1]:.0f})"


# -- plots ----------------------------------------------------------------------------------


def _rates_plot(agg: Aggregate) -> str:
    return png_img(rates_figure(agg))


def rates_figure(agg: Aggregate, *, title: str = "Failures over all streets") -> Any:
    """Each method's failure rate over the closed-loop runs with its 95 % Wilson interval."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.0))
    for i, r in enumerate(agg.rates):
        colour = COLOURS.get(r.method, "#555")
        ax.bar(i, r.rate * 100, color=colour, alpha=0.8, label=r.method)
        ax.errorbar(i, r.rate * 100, yerr=[[(r.rate - r.low) * 100], [(r.high - r.rate) * 100]],
                    color="k", capsize=6)  # fmt: skip
        ax.text(i, r.high * 100 + 2, f"{r.failures}/{r.runs}", ha="center", fontsize=9)
    ax.set_xticks(range(len(agg.rates)), [r.method for r in agg.rates])
    ax.set_ylabel("failure rate, % (95 % Wilson interval)")
    ax.set_ylim(0, 110)
    ax.set_title(title)
    return fig


def gap_figure(results: Sequence[WorldResult]) -> Any | None:
    """Each street's splat Min-Fréchet (and distance to its twin) against its steering gap."""
    points = _gap_points(results)
    if len(points) < 3:  # as rank_correlation
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    colour = COLOURS.get("splat", "#2166ac")
    ax.scatter([p[1] for p in points], [p[2] for p in points], color=colour, s=22,
               label="splat runs' Min-Fréchet")  # fmt: skip
    twins = [(p[1], p[3]) for p in points if p[3] is not None]
    if twins:
        ax.scatter([t[0] for t in twins], [t[1] for t in twins], facecolors="none",
                   edgecolors=colour, s=40, label="splat runs to their Real twin")  # fmt: skip
    for label, gap, frechet, _ in points:
        ax.annotate(label, (gap, frechet), fontsize=6, xytext=(3, 2), textcoords="offset points")
    rho = rank_correlation([p[1] for p in points], [p[2] for p in points])
    ax.set_xlabel("mean steering gap on the path, |splat - truth| (policy units)")
    ax.set_ylabel("metres")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"Does the splat's steering gap predict the drive? Spearman {rho:.2f}", fontsize=9)
    fig.tight_layout()
    return fig


def _profile_plot(world: WorldResult) -> str:
    if not world.profile:
        return '<p class="note">no along-route profile</p>'
    plt = pyplot()
    s = world.profile["s_m"]
    fig, ax = plt.subplots(figsize=(8.0, 2.6))
    styles = {-1.0: ":", 0.0: "-", 1.0: "--"}
    for off, row in zip(world.profile["offsets_m"], world.profile["psnr_db"], strict=True):  # type: ignore[call-overload]
        ys = [float("nan") if v is None else v for v in row]
        label = "on path" if off == 0 else f"{off:+g} m (+ = right)"
        ax.plot(s, ys, styles.get(off, "-"), color="#2166ac", label=label)
    for f in world.failures:
        if f.s_m is not None:
            ax.axvline(f.s_m, color=COLOURS.get(f.method, "#555"), alpha=0.7)
            ax.text(f.s_m, ax.get_ylim()[1], f"{f.method} {f.kind}", rotation=90, va="top",
                    fontsize=7, color=COLOURS.get(f.method, "#555"))  # fmt: skip
    ax.set_xlabel("station along the recorded path, m")
    ax.set_ylabel("splat vs truth PSNR, dB")
    ax.legend(fontsize=7, loc="lower left")
    truth, splat = _on_path(world, "steering_truth"), _on_path(world, "steering_splat")
    if truth is not None and splat is not None:
        gap = [
            float("nan") if a is None or b is None else b - a
            for a, b in zip(truth, splat, strict=True)
        ]
        twin = ax.twinx()
        twin.plot(s, gap, color="#b35806", lw=1.0, label="steering gap, splat - truth")
        twin.axhline(0.0, color="#b35806", lw=0.5, alpha=0.5)
        twin.set_ylabel("policy steering gap (units)", color="#b35806")
        twin.legend(fontsize=7, loc="lower right")
    ax.set_title(f"{world.label}: splat against the ground truth along the route")
    return png_img(fig)


# -- the page -------------------------------------------------------------------------------


def _gap_section(results: Sequence[WorldResult]) -> str:
    fig, prediction = gap_figure(results), gap_prediction(results)
    if fig is None or prediction is None:
        return ""
    return f"<p>{esc(prediction)}.</p>{png_img(fig)}"


def _world_section(folder: Path, world: WorldResult, tables: Mapping[str, Any]) -> str:
    methods = [r[1:] for r in tables["methods"][1] if r[0] == world.label]
    tuned = "looked at while tuning" if world.tuned else "not used while tuning"
    steps = ", ".join(f"{k} {v:.0f} s" for k, v in world.step_seconds.items())
    parts = [
        f'<h3 id="w-{esc(world.label)}">{esc(world.label)}: {esc(world.title)}</h3>',
        f'<p class="note">{esc(world.source)}; {tuned}; {world.seconds:.0f} s ({esc(steps)})</p>',
        html_table(tables["methods"][0][1:], methods),
        _profile_plot(world),
    ]
    for f in world.failures:
        psnr = ", ".join(
            f"{name} {fmt(v, '.1f')} dB" for name, v in zip(f.views, f.views_psnr_db, strict=False)
            if v is not None
        )  # fmt: skip
        where = (
            f"at {f.s_m:.0f} m ({f.route_share:.0%} of the route)"
            if f.s_m is not None and f.route_share is not None
            else ""
        )
        views = " | ".join(f.views)
        parts.append(
            f"<p><b>{esc(f.method)} {esc(f.run)}</b>: {esc(f.kind)} {esc(where)}. {esc(f.reason)}"
            f"<br>views 0.5 s before ({esc(views)}; PSNR against the truth: {esc(psnr or '-')})</p>"
        )
        if f.image:
            parts.append(_file_img(folder / "worlds" / world.label / f.image, f.run))
    return "".join(parts)


def write_bench_report(
    folder: Path,
    results: Sequence[WorldResult],
    agg: Aggregate | None = None,
    *,
    missing: Mapping[str, str] | None = None,
    name: str = "benchmark",
) -> Path:
    """Write ``report.html``, ``summary.md``, ``tables/*.csv`` and ``aggregate.json``.

    Returns:
        The HTML report's path.
    """
    folder = Path(folder)
    agg = agg or aggregate(list(results))
    tables = bench_tables(results, agg)
    untuned = [w for w in results if not w.tuned]
    agg_untuned = aggregate(untuned)
    for key, (headers, rows) in tables.items():
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(headers)
        writer.writerows(rows)
        write_text_atomic(folder / "tables" / f"{key}.csv", buffer.getvalue())
    write_text_atomic(folder / "aggregate.json", agg.model_dump_json(indent=2) + "\n")
    untuned_rates = bench_tables(untuned, agg_untuned)["rates"]
    titles = {
        "rates": "Failure rate per method over the closed-loop runs of all streets",
        "streets": "Per street: splat against Real (paired), Sim beside them",
        "splat": "The splat per street",
        "failures": "Every failure",
    }
    md = [f"# Benchmark {name}\n", f"**{agg.verdict}**\n",
          f"Streets not used while tuning ({len(untuned)}): {agg_untuned.verdict}\n"]  # fmt: skip
    for key, title in titles.items():
        md += [f"\n## {title}\n\n", _markdown(*tables[key])]
    md += ["\n## Failure rate per method, streets not used while tuning\n\n",
           _markdown(*untuned_rates)]  # fmt: skip
    prediction = gap_prediction(results)
    if prediction is not None:
        md += ["\n## What predicts the splat's drive\n\n", prediction, ".\n"]
    if missing:
        md += ["\n## Worlds without a result\n\n"] + [f"- {k}: {v}\n" for k, v in missing.items()]
    write_text_atomic(folder / "summary.md", "".join(md))
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    made = f"{len(results)} streets; generated {stamp} by cam2sim {esc(__version__)}"
    body = [
        f"<h1>cam2sim benchmark: {esc(name)}</h1>",
        f'<p class="note">{made}. {_GLOSSARY}</p>',
        f'<p class="verdict">{esc(agg.verdict)}</p>',
        f"<p>Streets not used while tuning ({len(untuned)}): {esc(agg_untuned.verdict)}</p>",
        _rates_plot(agg),
        html_table(*tables["rates"], caption=titles["rates"]),
        html_table(*untuned_rates, caption="The same, streets not used while tuning"),
        html_table(*tables["streets"], caption=titles["streets"]),
        html_table(*tables["splat"], caption=titles["splat"]),
        _gap_section(results),
        html_table(*tables["failures"], caption=titles["failures"]),
        "<h2>Streets</h2>",
        *(_world_section(folder, w, tables) for w in results),
    ]  # fmt: skip
    if missing:
        body.append("<h2>Worlds without a result</h2><ul>")
        body += [f"<li>{esc(k)}: {esc(v)} (see logs/{esc(k)}.log)</li>" for k, v in missing.items()]
        body.append("</ul>")
    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>cam2sim benchmark: {esc(name)}</title><style>{_CSS}</style></head><body>"
        + "".join(body)
        + "</body></html>\n"
    )
    path = folder / "report.html"
    write_text_atomic(path, page)
    return path
