"""A campaign on a two-node Ray cluster (a head and a worker node, both on this machine).

The same code path as a real cluster (`docs/cluster.md`): `RayCluster(address=...)` connects to
a running cluster instead of starting one, and its tasks are spread over the nodes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from campaign_helpers import PLAN, write_campaign

from cam2sim.campaign.executors import LocalPool, RayCluster
from cam2sim.campaign.runner import run_campaign

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
