from __future__ import annotations

import os

import pytest

from cam2sim.core.machine import available_cpus
from cam2sim.stages.pipeline import default_drive_workers


def test_a_ray_tasks_share_caps_the_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(64)), raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert available_cpus() == 64
    monkeypatch.setenv("OMP_NUM_THREADS", "16")  # what Ray sets for a task of 16 CPUs
    assert available_cpus() == 16
    # 3 cameras x 3 seeds on 16 CPUs: 4 processes; on 2 cores: one.
    assert default_drive_workers(9) == 4
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert default_drive_workers(9) == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "junk")
    assert available_cpus() == 64


def test_thread_pools_keep_to_the_cpus_a_task_was_given(monkeypatch: pytest.MonkeyPatch) -> None:
    import cv2

    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from cam2sim.core.backends import onnx_session
    from cam2sim.core.machine import keep_to_allotment

    before = cv2.getNumThreads()
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(64)), raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("LP_NUM_THREADS", raising=False)
    try:
        assert keep_to_allotment() is None  # nobody allotted CPUs: left as they are
        assert cv2.getNumThreads() == before
        assert "LP_NUM_THREADS" not in os.environ
        monkeypatch.setenv("OMP_NUM_THREADS", "3")  # a Ray task of 3 CPUs
        assert keep_to_allotment() == 3
        assert cv2.getNumThreads() == 3
        assert os.environ["LP_NUM_THREADS"] == "3"  # Mesa's rasteriser threads
    finally:
        cv2.setNumThreads(before)
    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])], "id",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    session = onnx_session(model.SerializeToString(), "a test")
    assert isinstance(session, ort.InferenceSession)
    assert session.get_session_options().intra_op_num_threads == 3


def test_children_get_their_allotment_and_never_more_than_this_process(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from cam2sim.core.machine import children_allotted

    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(16)), raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with children_allotted(4):
        assert os.environ["OMP_NUM_THREADS"] == os.environ["OPENBLAS_NUM_THREADS"] == "4"
    assert "OMP_NUM_THREADS" not in os.environ
    monkeypatch.setenv("OMP_NUM_THREADS", "2")  # this process was given 2 (a Ray task)
    with children_allotted(4):
        assert os.environ["OMP_NUM_THREADS"] == "2"
    assert os.environ["OMP_NUM_THREADS"] == "2"
    monkeypatch.setenv("MKL_NUM_THREADS", "9")
    with pytest.raises(RuntimeError), children_allotted(0):
        raise RuntimeError(os.environ["MKL_NUM_THREADS"])
    assert os.environ["MKL_NUM_THREADS"] == "9"  # restored after an error too
    with children_allotted(0):
        assert os.environ["NUMBA_NUM_THREADS"] == "1"  # at least one
