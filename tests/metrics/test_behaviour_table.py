"""The Real group (recorded + closed-loop real runs) and the paper-layout behaviour table."""

from __future__ import annotations

import numpy as np

from cam2sim.metrics.behaviour import behaviour_table, evaluate_with_real_runs
from cam2sim.metrics.drive_io import DriveRun


def _run(
    name: str,
    method: str,
    lateral: float,
    *,
    end: float = 100.0,
    real: bool = False,
    seed: int | None = None,
) -> DriveRun:
    x = np.arange(0.0, end, 0.5)
    y = lateral * np.sin(x / 15.0)
    if end < 100.0:  # a failed run leaves the road to the left at its end
        y[-10:] += np.linspace(0.5, 4.0, 10)
    t = x / 8.0
    steer_t = t[::3]
    return DriveRun(
        name=name,
        method=method,
        real=real,
        t=t,
        xy=np.stack([x, y], -1),
        crs=None,
        steering_t=steer_t,
        steering=0.1 * np.sin(steer_t * (2.0 + lateral)),
        seed=seed,
    )


def test_completed_real_runs_join_the_references_and_failed_ones_count_as_failures() -> None:
    recorded = _run("real/recorded", "real", 0.0, real=True)
    runs = [
        _run("real/a", "real", 0.3),
        _run("real/b", "real", -0.4),
        _run("real/c", "real", 0.2, end=40.0),
        _run("splat/a", "drive-splat", 0.8),
        _run("sim/a", "drive-raster", 1.2, end=30.0),
    ]
    ev = evaluate_with_real_runs([recorded], runs)
    by_name = {r.name: r for r in ev.metrics.runs}
    assert by_name["real/a"].real
    assert by_name["real/b"].real
    assert not by_name["real/c"].real
    assert by_name["real/c"].failure == "incomplete"
    # The completed closed-loop runs widen the corridor beyond the recorded line.
    assert ev.metrics.corridor_mean_width_m > 0.2
    real = next(s for s in ev.metrics.methods if s.method == "real")
    assert (real.runs, real.successes) == (4, 3)
    assert by_name["splat/a"].success
    assert not by_name["sim/a"].success


def test_the_table_has_real_then_splat_then_sim_columns() -> None:
    recorded = _run("real/recorded", "real", 0.0, real=True)
    runs = [
        _run("sim/a", "drive-raster", 1.2, end=30.0, seed=4),
        _run("splat/a", "drive-splat", 0.8, seed=4),
        _run("real/a", "real", 0.3, seed=4),
    ]
    table = behaviour_table(evaluate_with_real_runs([recorded], runs).metrics)
    assert table.columns == ("Real", "splat", "Sim")
    rows = dict(table.rows)
    assert rows["runs"] == ("2", "1", "1")
    assert rows["failure rate"] == ("0/2", "0/1", "1/1")
    assert rows["Min-Fréchet (m)"][2] == "-"  # averages over successful runs only
    # splat/a's twin is real/a (seed 4): sine amplitudes 0.8 and 0.3, 0.5 m apart at most.
    assert rows["to Real twin (m)"] == ("-", "0.50", "-")
    assert "| metric | Real | splat | Sim |" in table.markdown()
