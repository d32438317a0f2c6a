"""A campaign on a two-node Ray cluster (a head and a worker node, both on this machine), and
splat runs sharing a GPU.

The same code path as a real cluster (`docs/cluster.md`): `RayCluster(address=...)` connects to
a running cluster instead of starting one, and its tasks are spread over the nodes.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import campaign_helpers
import pytest
from campaign_helpers import PLAN, probe_execute, slow_execute, write_campaign

from cam2sim.campaign.executors import LocalPool, RayCluster
from cam2sim.campaign.runner import CampaignResult, run_campaign
from cam2sim.campaign.state import CampaignState
from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Iterator

ray = pytest.importorskip("ray")
cluster_utils = pytest.importorskip("ray.cluster_utils")


@pytest.fixture
def two_nodes() -> Iterator[str]:
    """A head node and one worker node of one CPU each; the cluster's address."""
    cluster = cluster_utils.Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False}
    )
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    try:
        yield cluster.address
    finally:
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()


def test_a_campaign_runs_on_a_two_node_cluster(tmp_path: Path, two_nodes: str) -> None:
    plan_text = PLAN.replace("seeds: [0]", "seeds: [0, 1]")
    local = run_campaign(
        write_campaign(tmp_path, plan_text + "output: local\n", name="local"),
        executor=LocalPool(2),
    )
    on_cluster = run_campaign(
        write_campaign(tmp_path, plan_text + "output: cluster\n", name="cluster"),
        executor=RayCluster(address=two_nodes),
    )
    assert on_cluster.ran == local.ran == 4
    assert [r.status for r in on_cluster.rows] == ["done"] * 4
    keys = ("spec_id", "completion", "min_frechet_m", "corridor_violation_pct")
    assert [[getattr(r, k) for k in keys] for r in on_cluster.rows] == [
        [getattr(r, k) for k in keys] for r in local.rows
    ]
    # The connection was to the running cluster (two nodes), not to a new local instance,
    # and it was left running for its owner.
    ray.init(address=two_nodes)
    assert len([n for n in ray.nodes() if n["Alive"]]) == 2


@pytest.fixture
def doomed_node() -> Iterator[tuple[Any, Any]]:
    """A head node and a worker node of one CPU each: the cluster and the worker node."""
    cluster = cluster_utils.Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False}
    )
    node = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    try:
        yield cluster, node
    finally:
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()


def test_the_runs_of_a_lost_node_run_again_on_the_others(
    tmp_path: Path, doomed_node: tuple[Any, Any]
) -> None:
    ray.cloudpickle.register_pickle_by_value(campaign_helpers)  # the slow task, sent by value
    cluster, node = doomed_node
    plan = write_campaign(
        tmp_path,
        PLAN.replace("seeds: [0]", "seeds: [0, 1]").replace("{lateral_m: [0.0, 0.3]}", "{}"),
    )
    done: list[CampaignResult] = []
    driver = threading.Thread(
        target=lambda: done.append(
            run_campaign(plan, executor=RayCluster(cluster.address, task=slow_execute))
        )
    )
    driver.start()
    logs = tmp_path / "plan-campaign" / "logs"
    until = time.monotonic() + 60
    while len(list(logs.glob("*.started"))) < 2 and time.monotonic() < until:
        time.sleep(0.2)  # both runs under way, one on each node
    assert len(list(logs.glob("*.started"))) == 2
    cluster.remove_node(node, allow_graceful=False)  # its raylet and workers killed
    driver.join(timeout=120)
    (result,) = done
    # The lost node's run ran again on the head node; both finished; nothing half-written.
    assert [r.status for r in result.rows] == ["done", "done"]
    state = CampaignState.load(result.folder / "state.json")
    assert sorted(r.attempts for r in state.runs.values()) == [1, 1]
    runs = tmp_path / "ws" / "runs"
    finished = [p for p in runs.iterdir() if not p.name.startswith(".")]
    assert len(finished) == 2
    assert all((p / "run.json").is_file() and (p / "trajectory.csv").is_file() for p in finished)


@pytest.fixture
def one_gpu() -> Iterator[None]:
    """A local Ray instance of 4 CPUs and one GPU (declared: Ray schedules it, none is used)."""
    ray.init(num_cpus=4, num_gpus=1, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


def _probes(folder: Path) -> list[list[str]]:
    """Each probe's log: its start and end time, its process id, its GPU's sharers."""
    return [p.read_text().split() for p in sorted((folder / "logs").glob("*.log"))]


def _spans(folder: Path) -> list[tuple[float, float]]:
    """When each probe ran (its log's two times), in start order."""
    return sorted((float(a), float(b)) for a, b, _pid, _share in _probes(folder))


def test_splat_runs_take_a_gpu_or_a_share_of_one(tmp_path: Path, one_gpu: None) -> None:
    ray.cloudpickle.register_pickle_by_value(campaign_helpers)  # the probe, sent by value
    plan_text = PLAN.replace("cameras: [none]", "cameras: [splat]").replace(
        "seeds: [0]", "seeds: [0, 1]"
    )
    plan_text = plan_text.replace("{lateral_m: [0.0, 0.3]}", "{}")
    progress: list[tuple[str, int]] = []
    whole = run_campaign(
        write_campaign(tmp_path, plan_text + "output: whole\n", name="whole"),
        executor=RayCluster(task=probe_execute),
        progress=lambda task, done, _total: progress.append((task, done)),
    )
    # Each run was given the GPU and said so; one GPU a run: one at a time.
    assert [r.place for r in whole.rows] == [f"{_host()} GPU 0"] * 2
    assert {share for *_, share in _probes(whole.folder)} == {"1"}
    (_a0, a1), (b0, _b1) = _spans(whole.folder)
    assert b0 >= a1 - 0.05
    # The progress shows the GPU at work: a bar of the runs it did.
    assert (f"  runs on {_host()} GPU 0", 2) in progress
    assert "Where the runs ran" in (whole.folder / "report.html").read_text()
    # Half a GPU a run: both at once on the one GPU.
    shared = run_campaign(
        write_campaign(tmp_path, plan_text + "output: shared\n", name="shared"),
        executor=RayCluster(task=probe_execute, gpus_per_job=0.5),
    )
    assert [r.place for r in shared.rows] == [f"{_host()} GPU 0"] * 2
    # Each run was told it shares its GPU with one other (a splat's time cap doubles).
    assert {share for *_, share in _probes(shared.folder)} == {"2"}
    (_a0, a1), (b0, _b1) = _spans(shared.folder)
    assert b0 < a1 - 0.5


def test_gpu_runs_reuse_their_workers_and_a_killed_one_is_retried(
    tmp_path: Path, one_gpu: None
) -> None:
    ray.cloudpickle.register_pickle_by_value(campaign_helpers)  # the probe, sent by value
    plan_text = PLAN.replace("cameras: [none]", "cameras: [splat]")
    plan_text = plan_text.replace("{lateral_m: [0.0, 0.3]}", "{}")
    many = plan_text.replace("seeds: [0]", "seeds: [0, 1, 2, 3, 4, 5]")
    result = run_campaign(
        write_campaign(tmp_path, many + "output: many\n", name="many"),
        executor=RayCluster(task=probe_execute, gpus_per_job=0.5),
    )
    # Six GPU runs on two half-GPU slots: two worker processes ran them, three each.
    assert len(result.rows) == 6
    assert [r.status for r in result.rows] == ["failed"] * 6  # a probe's outcome: no drive
    pids = [pid for _a, _b, pid, _share in _probes(result.folder)]
    assert sorted(pids.count(p) for p in set(pids)) == [3, 3]
    # A worker whose process exits mid-run (constant:13, on its first attempt) is restarted and
    # its run done again; the other runs go on, every run is reported once.
    killed = plan_text.replace("[pure-pursuit]", '[pure-pursuit, "constant:13", "constant:12"]')
    result = run_campaign(
        write_campaign(tmp_path, killed + "output: killed\n", name="killed"),
        executor=RayCluster(task=probe_execute, gpus_per_job=0.5),
    )
    assert [r.status for r in result.rows] == ["failed"] * 3  # each probe ran to its end
    assert len(list((result.folder / "logs").glob("*.died"))) == 1
    state = CampaignState.load(result.folder / "state.json")
    assert sorted(r.attempts for r in state.runs.values()) == [1, 1, 1]


def _host() -> str:
    import socket

    return socket.gethostname()


@pytest.mark.parametrize("share", [0.0, 1.5, -1.0])
def test_a_gpu_share_must_be_part_of_one_or_whole_gpus(share: float) -> None:
    with pytest.raises(ConfigError, match="a share of one GPU in \\(0, 1\\]"):
        RayCluster(gpus_per_job=share)
