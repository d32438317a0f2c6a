"""Campaigns on the local process pool: runs, resume, failure isolation, summary, the command."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from campaign_helpers import PLAN, crashing_execute, full_disk_execute, needs_egl, write_campaign
from typer.testing import CliRunner

from cam2sim.campaign import worker
from cam2sim.campaign.executors import LocalPool
from cam2sim.campaign.runner import campaign_lock, run_campaign
from cam2sim.campaign.state import CampaignState
from cam2sim.cli.main import app
from cam2sim.core.errors import WorkspaceError
from cam2sim.core.table import read_table
from cam2sim.metrics.benchmark import wilson_interval
from cam2sim.scenario.synthetic import StreetSpec
from conftest import truth_workspace


def _runs(ws: Path) -> list[Path]:
    return sorted(p for p in (ws / "runs").iterdir() if p.is_dir())


@needs_egl
def test_a_campaign_runs_resumes_and_summarises(tmp_path: Path) -> None:
    plan = write_campaign(tmp_path, PLAN.replace("cameras: [none]", "cameras: [none, raster]"))
    result = run_campaign(plan, executor=LocalPool(2))
    assert (result.specs, result.ran, result.failed) == (4, 4, 0)
    folder = tmp_path / "plan-campaign"
    assert result.folder == folder
    state = CampaignState.load(folder / "state.json")
    assert len(state.done()) == 4
    runs = _runs(tmp_path / "ws")
    assert sorted(r.run_id for r in state.runs.values()) == [p.name for p in runs]
    # Results are ordinary drive runs; the perturbed start is recorded and applied.
    by_offset = {}
    for row in result.rows:
        meta = json.loads((tmp_path / "ws" / "runs" / str(row.run_id) / "run.json").read_text())
        assert meta["options"]["start_offset"] == [row.lateral_m, 0.0]
        assert meta["camera"] == row.camera
        if row.camera == "none":
            by_offset[row.lateral_m] = read_table(
                tmp_path / "ws" / "runs" / str(row.run_id) / "trajectory.csv"
            )
    gap = math.hypot(
        by_offset[0.3]["x"][0] - by_offset[0.0]["x"][0],
        by_offset[0.3]["y"][0] - by_offset[0.0]["y"][0],
    )
    assert abs(gap - 0.3) < 0.02
    # One summary row per recording, policy and camera, with metrics of the finished runs.
    assert [(s.camera, s.runs, s.done, s.failed) for s in result.summary] == [
        ("none", 2, 2, 0),
        ("raster", 2, 2, 0),
    ]
    assert all(s.completion_mean is not None and s.completion_mean > 0.5 for s in result.summary)
    summary = json.loads((folder / "summary.json").read_text())
    assert len(summary["summary"]) == 2
    assert len(summary["runs"]) == 4
    assert (folder / "summary.csv").read_text().splitlines()[0].startswith("workspace,policy,")
    assert (folder / "metrics" / "ws" / "metrics.json").is_file()
    # The report: a row per camera with its completion rate and interval, and the plot.
    page = (folder / "report.html").read_text()
    assert page.count("<td>pure-pursuit</td>") == 2
    for row in result.summary:
        low, high = wilson_interval(row.successes, row.done)
        cells = f"<td>{row.successes}/{row.done}</td><td>{100 * low:.0f}-{100 * high:.0f} %</td>"
        assert f"<td>{row.camera}</td>" in page
        assert cells in page
    assert page.count("data:image/png;base64,") == 1
    assert "Every run finished." in page

    # A second campaign does nothing; a deleted run folder is run again.
    again = run_campaign(plan, executor=LocalPool(2))
    assert again.ran == 0
    assert _runs(tmp_path / "ws") == runs
    shutil.rmtree(runs[0])
    third = run_campaign(plan, executor=LocalPool(2))
    assert third.ran == 1
    assert len(_runs(tmp_path / "ws")) == 4


def test_failed_runs_are_recorded_with_their_logs_and_the_rest_goes_on(tmp_path: Path) -> None:
    plan = write_campaign(
        tmp_path,
        PLAN.replace("[ws]", "[ws, no-such-ws]")
        .replace("[pure-pursuit]", '[pure-pursuit, "constant:nan"]')
        .replace("{lateral_m: [0.0, 0.3]}", "{}"),
    )
    result = run_campaign(plan, executor=LocalPool(2))
    status = {(r.workspace, r.policy): r.status for r in result.rows}
    assert status == {
        ("ws", "pure-pursuit"): "done",
        ("ws", "constant:nan"): "failed",
        ("no-such-ws", "pure-pursuit"): "failed",
        ("no-such-ws", "constant:nan"): "failed",
    }
    state = CampaignState.load(result.folder / "state.json")
    records = {r.workspace + " " + (r.error or ""): r for r in state.runs.values()}
    bad_policy = next(r for k, r in records.items() if k.startswith("ws ConfigError"))
    assert "constant:VALUE needs a finite number" in str(bad_policy.error)
    bad_id = next(r.spec_id for r in result.rows if r.workspace == "ws" and r.status != "done")
    log = (result.folder / "logs" / f"{bad_id}.log").read_text()
    assert "Traceback" in log
    assert "ConfigError" in log
    missing = next(r for k, r in records.items() if k.startswith("no-such-ws"))
    assert "is not a cam2sim workspace" in str(missing.error)
    assert [(s.workspace, s.policy, s.done, s.failed) for s in result.summary] == [
        ("ws", "pure-pursuit", 1, 0),
        ("ws", "constant:nan", 0, 1),
        ("no-such-ws", "pure-pursuit", 0, 1),
        ("no-such-ws", "constant:nan", 0, 1),
    ]
    # The report lists the three runs that did not finish, each with its log.
    page = (result.folder / "report.html").read_text()
    assert "Runs that did not finish" in page
    assert page.count("<td>failed</td>") == 3
    assert f"<td>logs/{bad_id}.log</td>" in page
    # It renders again from summary.json alone.
    from cam2sim.report.campaign import report_from_summary

    (result.folder / "report.html").unlink()
    assert report_from_summary(result.folder).read_text().count("<td>failed</td>") == 3
    # Failed runs are tried again, unless asked not to; finished ones never.
    assert run_campaign(plan, executor=LocalPool(2), retry_failed=False).ran == 0
    retried = run_campaign(plan, executor=LocalPool(2))
    assert retried.ran == 3
    assert CampaignState.load(result.folder / "state.json").runs[bad_id].attempts == 2


def test_a_run_past_its_time_limit_is_recorded_as_timed_out(tmp_path: Path) -> None:
    plan = write_campaign(tmp_path, PLAN.replace("timeout_s: 120", "timeout_s: 0.001"))
    result = run_campaign(plan, executor=LocalPool(1))
    assert [r.status for r in result.rows] == ["timeout", "timeout"]
    log = (result.folder / "logs" / f"{result.rows[0].spec_id}.log").read_text()
    assert "RunTimeoutError: the run took longer than timeout_s=0.001" in log
    runs = tmp_path / "ws" / "runs"
    assert not runs.exists() or not list(runs.iterdir())  # no half run is left


def test_a_crashing_worker_fails_only_its_own_run(tmp_path: Path) -> None:
    plan = write_campaign(
        tmp_path,
        PLAN.replace("[pure-pursuit]", '[pure-pursuit, "constant:13"]').replace(
            "{lateral_m: [0.0, 0.3]}", "{}"
        ),
    )
    result = run_campaign(plan, executor=LocalPool(2, task=crashing_execute))
    status = {r.policy: r.status for r in result.rows}
    assert status == {"pure-pursuit": "done", "constant:13": "crashed"}
    crashed = next(r for r in result.rows if r.status == "crashed")
    log = (result.folder / "logs" / f"{crashed.spec_id}.log").read_text()
    assert "the worker process died during the run" in log


def test_a_full_disk_fails_its_run_and_a_resume_redoes_only_that_one(tmp_path: Path) -> None:
    plan = write_campaign(
        tmp_path,
        PLAN.replace("[pure-pursuit]", '[pure-pursuit, "constant:0.01"]').replace(
            "{lateral_m: [0.0, 0.3]}", "{}"
        ),
    )
    result = run_campaign(plan, executor=LocalPool(1, task=full_disk_execute))
    status = {r.policy: r.status for r in result.rows}
    assert status == {"pure-pursuit": "done", "constant:0.01": "failed"}
    state = CampaignState.load(result.folder / "state.json")
    failed = next(r for r in state.runs.values() if r.status == "failed")
    assert failed.error is not None
    assert failed.error.startswith("the disk is full (")
    assert "run the campaign again" in failed.error
    # Nothing half-written: the full disk's run left no folder, hidden or not.
    assert len(_runs(tmp_path / "ws")) == 1
    assert not [p for p in (tmp_path / "ws" / "runs").iterdir() if p.name.startswith(".")]
    # Space freed: the same campaign runs only the failed run again.
    again = run_campaign(plan, executor=LocalPool(1))
    assert again.ran == 1
    assert [r.status for r in again.rows] == ["done", "done"]
    assert len(_runs(tmp_path / "ws")) == 2


# The child takes Ctrl-C as a terminal's program does, even where the test runs in the
# background: a non-interactive shell starts its background jobs with SIGINT ignored, which a
# Python child inherits (and then never raises KeyboardInterrupt).
_INTERRUPTED = """
import signal
import sys
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.path[:0] = [{tests!r}, {here!r}]
from campaign_helpers import slow_execute
from cam2sim.campaign.executors import LocalPool
from cam2sim.campaign.runner import run_campaign
run_campaign({plan!r}, executor=LocalPool(1, task=slow_execute))
"""


def test_ctrl_c_keeps_what_finished_and_a_resume_does_the_rest(tmp_path: Path) -> None:
    here = Path(__file__).parent
    plan = write_campaign(tmp_path, PLAN.replace("seeds: [0]", "seeds: [0, 1, 2]"))
    script = _INTERRUPTED.format(tests=str(here.parent), here=str(here), plan=str(plan))
    child = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)
    state_path = tmp_path / "plan-campaign" / "state.json"
    until = time.monotonic() + 120
    while time.monotonic() < until and child.poll() is None:
        if state_path.is_file() and len(CampaignState.load(state_path).done()) >= 1:
            break
        time.sleep(0.2)
    # Six runs of 4 s or more: a loaded machine still interrupts the campaign under way.
    os.killpg(child.pid, signal.SIGINT)  # Ctrl-C reaches the driver and its workers
    assert child.wait(timeout=60) != 0
    kept = CampaignState.load(state_path).done()
    assert 1 <= len(kept) < 6
    finished = _runs(tmp_path / "ws")
    assert all((p / "run.json").is_file() for p in finished if not p.name.startswith("."))
    # The resume runs only what is missing, and keeps what finished.
    resumed = run_campaign(plan, executor=LocalPool(2))
    assert resumed.ran == 6 - len(kept)
    assert [r.status for r in resumed.rows] == ["done"] * 6
    done = [p for p in _runs(tmp_path / "ws") if not p.name.startswith(".")]
    assert len(done) == 6


def test_runs_are_judged_in_the_ground_truth_where_there_is_one(tmp_path: Path) -> None:
    truth_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    plan = PLAN.replace("{lateral_m: [0.0, 0.3]}", "{}")
    auto = run_campaign(write_campaign(tmp_path, plan, name="auto"), executor=LocalPool(1))
    on_map = run_campaign(
        write_campaign(tmp_path, plan.replace("drive: {", "drive: {judge: map, "), name="map"),
        executor=LocalPool(1),
    )
    judged = [
        json.loads((tmp_path / "ws" / "runs" / str(r.rows[0].run_id) / "run.json").read_text())[
            "options"
        ]["judge"]
        for r in (auto, on_map)
    ]
    assert judged == ["truth", "map"]  # auto: as cam2sim run judges
    assert auto.rows[0].spec_id != on_map.rows[0].spec_id


def test_the_campaign_command_prints_the_summary(tmp_path: Path) -> None:
    plan = write_campaign(tmp_path, PLAN.replace("{lateral_m: [0.0, 0.3]}", "{}"))
    out = CliRunner().invoke(app, ["campaign", str(plan), "--workers", "1"])
    assert out.exit_code == 0, out.output
    assert "campaign summary" in out.output
    assert "1 of 1 runs done now (0 failed" in out.output
    bad = write_campaign(tmp_path, "workspaces: [ws]\nseed: [1]\n", name="bad")
    out = CliRunner().invoke(app, ["campaign", str(bad)])
    assert out.exit_code == 1
    assert "seed: unknown key (did you mean 'seeds'?)" in out.output


def test_a_run_stuck_where_the_timeout_signal_cannot_reach_is_killed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    killed = threading.Event()
    monkeypatch.setattr(worker, "HARD_LIMIT_GRACE_S", 0.05)
    monkeypatch.setattr(worker, "_kill", lambda seconds: killed.set())
    monkeypatch.setattr(signal, "setitimer", lambda *_: None)  # as if stuck in native code
    with worker._deadline(0.01):
        assert killed.wait(10)


def test_one_campaign_folder_serves_one_process_at_a_time(tmp_path: Path) -> None:
    plan = write_campaign(tmp_path)
    with campaign_lock(tmp_path / "plan-campaign"), pytest.raises(WorkspaceError, match="another"):
        run_campaign(plan, executor=LocalPool(1))


def test_the_report_names_recordings_by_what_tells_them_apart() -> None:
    from cam2sim.report.campaign import short_names

    names = short_names(
        ["/tmp/bench/worlds/a/ws", "/tmp/bench/worlds/b-r0/ws", "/tmp/bench/worlds/a/ws"]
    )
    assert names == {"/tmp/bench/worlds/a/ws": "a/ws", "/tmp/bench/worlds/b-r0/ws": "b-r0/ws"}
    assert short_names(["ws"]) == {"ws": "ws"}  # one recording keeps its name
    assert short_names(["/data/ws"]) == {"/data/ws": "/data/ws"}
    assert short_names(["runs/a", "runs/a2"]) == {"runs/a": "a", "runs/a2": "a2"}
