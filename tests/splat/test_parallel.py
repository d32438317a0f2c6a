"""Chunks trained in worker processes (``concurrent_chunks``), on the CPU with tiny chunks.

The process path must write what the one-process loop writes: the same models, bit for bit, and
the same results (three chunks, two at a time: the third loads ahead and waits for a slot); a
failing chunk is named after the others finished; an interrupt ends the workers.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
from pathlib import Path

import pytest

pytest.importorskip("torch")

import torch
from test_train import fast_options, make_prepared_scene

from cam2sim.core.errors import StageError
from cam2sim.splat import model as gm
from cam2sim.splat.train import SceneTrainResult, TrainOptions, train_scene

TINY = {"n_frames": 8, "chunks": ((0, 5), (3, 8), (1, 6)), "size": (32, 24)}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _options(**changes: object) -> TrainOptions:
    base: dict[str, object] = {"max_steps": 12, "min_steps": 12, "val_every": 4, "sky_points": 30}
    return fast_options(**(base | changes))


def _comparable(result: SceneTrainResult) -> list[dict[str, object]]:
    """Each chunk's result without what differs between runs (timing, folder)."""
    return [
        {
            k: v
            for k, v in dataclasses.asdict(c).items()
            if k not in {"train_seconds", "model_path", "phase_ms"}
        }
        for c in result.chunks
    ]


def test_worker_processes_write_what_the_one_process_loop_writes(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path / "ws", **TINY)  # type: ignore[arg-type]
    sequential = train_scene(
        prep, options=_options(concurrent_chunks=1), models_dir=tmp_path / "sequential"
    )
    seen: list[tuple[str, int, int | None]] = []
    parallel = train_scene(
        prep,
        options=_options(concurrent_chunks=2),
        models_dir=tmp_path / "parallel",
        progress=lambda task, done, total: seen.append((task, done, total)),
    )
    assert _comparable(parallel) == _comparable(sequential)
    assert [c.model_path for c in parallel.chunks] == [
        tmp_path / "parallel" / f"chunk_{c:02d}.pt" for c in range(3)
    ]
    assert sorted(p.name for p in (tmp_path / "parallel").iterdir()) == sorted(
        p.name for p in (tmp_path / "sequential").iterdir()
    )
    for a, b in zip(sequential.chunks, parallel.chunks, strict=True):
        one, two = gm.load_chunk_model(a.model_path), gm.load_chunk_model(b.model_path)
        assert one.header == two.header
        for x, y in ((one.gaussians, two.gaussians), (one.sky, two.sky)):
            for name in gm.PARAM_NAMES:
                torch.testing.assert_close(x.params[name], y.params[name], rtol=0, atol=0)
        torch.testing.assert_close(one.appearance, two.appearance, rtol=0, atol=0)
    # Progress adds up the workers' steps, never goes back, and ends at the cap.
    assert {task for task, _, _ in seen} == {"splat steps"}
    assert {total for _, _, total in seen} == {36}
    done = [d for _, d, _ in seen]
    assert done == sorted(done)
    assert done[-1] == 36
    assert not multiprocessing.active_children()


def test_a_failing_chunk_is_named_after_the_others_finish(tmp_path: Path) -> None:
    # Chunk 1 holds frame 2 alone, which is held out: it has nothing to train on.
    prep = make_prepared_scene(
        tmp_path / "ws", n_frames=5, chunks=((0, 5), (2, 3), (1, 5)), size=(32, 24)
    )
    with pytest.raises(
        StageError, match=r"1 of 3 chunks failed in worker processes \(chunk 1: StageError: chunk 1"
    ):
        train_scene(prep, options=_options(concurrent_chunks=2, max_steps=4, min_steps=4))
    models = tmp_path / "ws" / "splat" / "models"
    assert sorted(p.name for p in models.glob("*.pt")) == ["chunk_00.pt", "chunk_02.pt"]
    assert not multiprocessing.active_children()


def test_an_interrupt_ends_the_workers(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path / "ws", **TINY)  # type: ignore[arg-type]

    def interrupt(_task: str, done: int, _total: int | None) -> None:
        if done > 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_scene(prep, options=_options(concurrent_chunks=2, max_steps=2000), progress=interrupt)
    assert not multiprocessing.active_children()


def test_concurrency_is_validated() -> None:
    with pytest.raises(ValueError, match="concurrent_chunks=0"):
        TrainOptions(concurrent_chunks=0)


def test_the_gpu_slots_leave_no_chunk_to_train_alone_at_the_end() -> None:
    from cam2sim.splat.parallel import cuda_slots

    # 5 chunks: 3 then 2, not 2, 2 and one alone at half the GPU's pace (KITTI 03 on an H100).
    assert cuda_slots(5, 80.0) == 3
    assert cuda_slots(4, 80.0) == 2  # two rounds of two
    assert cuda_slots(3, 80.0) == 3
    assert cuda_slots(2, 80.0) == 2
    assert cuda_slots(1, 80.0) == 1
    assert cuda_slots(5, 24.0) == 2  # a small card keeps two
    assert all(1 <= cuda_slots(n, 80.0) <= min(n, 3) for n in range(1, 30))


def test_a_shared_gpu_keeps_the_chunks_its_memory_holds(monkeypatch: pytest.MonkeyPatch) -> None:
    import types

    from cam2sim.core.machine import GPU_SHARERS_VARIABLE
    from cam2sim.splat import train as train_module

    card = types.SimpleNamespace(total_memory=int(79.2 * 2**30))  # an H100's, as torch says
    monkeypatch.setattr(torch.cuda, "get_device_properties", lambda _device: card)
    monkeypatch.delenv(GPU_SHARERS_VARIABLE, raising=False)
    assert train_module._default_slots("cuda:0", 5) == 3  # a GPU of its own: 3, then 2
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "2")
    assert train_module._default_slots("cuda:0", 5) == 2  # a chunk alone leaves it idle
    # Five benchmark worlds on one H100 with two chunks each held 5-10 GiB a worker and ran
    # out of memory: four or more sharers of 80 GB keep one chunk each.
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "5")
    assert train_module._default_slots("cuda:0", 5) == 1
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "4")
    assert train_module._default_slots("cuda:0", 5) == 1
    card.total_memory = int(139.8 * 2**30)  # an H200 holds two each for four
    assert train_module._default_slots("cuda:0", 5) == 2
    assert train_module._default_slots("cuda:0", 1) == 1
    assert train_module._default_slots("cpu", 5) == 1


def _out_of_memory_first(prep_dir: Path, **kwargs: object) -> SceneTrainResult:
    """``train_scene``, but chunk 1's worker runs out of GPU memory the first ``OOM_TIMES``.

    Spawned workers import this module by name; the attempts are counted in files beside the
    models (``OOM_TIMES`` of them in the folder's name: ``oom-N``).
    """
    (chunk,) = kwargs["chunk_ids"]  # type: ignore[misc]
    models = Path(kwargs["models_dir"])  # type: ignore[arg-type]
    times = int(models.name.split("-")[1])
    models.mkdir(parents=True, exist_ok=True)
    attempts = len(list(models.glob(f"attempt-{chunk}-*")))
    (models / f"attempt-{chunk}-{attempts}").touch()
    if chunk == 1 and attempts < times:
        progress = kwargs["progress"]
        progress("splat steps", 1, 12)  # type: ignore[operator] # ready: it had a slot
        msg = "CUDA out of memory. Tried to allocate 102.00 MiB. GPU 0 has a total capacity"
        raise torch.OutOfMemoryError(msg)
    return train_scene(prep_dir, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("times", [1, 3])
def test_a_chunk_out_of_gpu_memory_trains_again_with_a_slot_fewer(
    tmp_path: Path, times: int, caplog: pytest.LogCaptureFixture
) -> None:
    from cam2sim.splat.parallel import OUT_OF_MEMORY_RETRIES, train_chunks_in_processes
    from cam2sim.splat.scene import SceneRecord

    prep = make_prepared_scene(tmp_path / "ws", **TINY)  # type: ignore[arg-type]
    scene = SceneRecord.load(prep / "scene.json")
    models = tmp_path / f"oom-{times}"
    options = dataclasses.replace(_options(max_steps=6, min_steps=6), device="cpu")

    def train() -> SceneTrainResult:
        return train_chunks_in_processes(
            _out_of_memory_first, prep, scene, (0, 1, 2), options, models_dir=models, in_flight=2
        )

    attempts = min(times, OUT_OF_MEMORY_RETRIES) + 1
    with caplog.at_level("WARNING", logger="cam2sim.splat.parallel"):
        if times > OUT_OF_MEMORY_RETRIES:  # out of memory every time: it fails, named
            with pytest.raises(StageError, match=r"1 of 3 chunks .*chunk 1: OutOfMemoryError"):
                train()
        else:
            result = train()
            assert [c.chunk_id for c in result.chunks] == [0, 1, 2]
            assert all(c.model_path.is_file() for c in result.chunks)
    assert len(list(models.glob("attempt-1-*"))) == attempts
    assert len(list(models.glob("attempt-0-*"))) == len(list(models.glob("attempt-2-*"))) == 1
    retries = [r.getMessage() for r in caplog.records if "ran out of GPU memory" in r.getMessage()]
    assert len(retries) == attempts - 1
    assert "1 chunk(s) at a time from now (retry 1 of" in retries[0]
    assert not multiprocessing.active_children()


def test_a_slot_freed_by_a_retry_is_not_taken_past_the_fewer_slots() -> None:
    import threading

    from cam2sim.splat.parallel import ChunkOutcomes, _Pool

    outcomes = ChunkOutcomes((0, 1, 2), "in a test")
    pool = _Pool((0, 1, 2), (), 2, outcomes, 10, lambda *_: None, cpus=1)
    pool.go = {c: threading.Event() for c in (0, 1, 2)}
    pool.ready = [0, 1]
    pool._grant()
    assert pool.training == {0, 1}
    pool._failed(0, "OutOfMemoryError: CUDA out of memory. Tried to allocate 2 MiB\ntraceback")
    assert pool.in_flight == 1
    assert 0 not in outcomes  # not failed: it trains again
    pool.training.discard(0)  # its worker ended (what _restart does)
    pool.restarting.discard(0)
    pool.ready.append(0)  # loaded again: chunk 1 still trains, so it waits
    pool._grant()
    assert pool.training == {1}
    pool._failed(1, "StageError: chunk 1 has nothing to train on")  # not memory: failed
    assert 1 in outcomes
    pool.training.discard(1)
    pool._grant()
    assert pool.training == {0}


def test_the_longest_chunks_train_first(tmp_path: Path) -> None:
    from cam2sim.splat.parallel import largest_first
    from cam2sim.splat.scene import SceneRecord

    prep = make_prepared_scene(tmp_path / "ws", n_frames=10, chunks=((0, 3), (2, 10), (5, 10)))
    scene = SceneRecord.load(prep / "scene.json")
    lengths = {c.id: c.end_m - c.start_m for c in scene.chunks}
    assert lengths[1] > lengths[2] > lengths[0]
    assert largest_first(scene, (0, 1, 2)) == (1, 2, 0)
    assert largest_first(scene, (0, 2)) == (2, 0)


def test_a_slot_waits_for_the_longer_chunk_still_loading() -> None:
    import threading

    from cam2sim.splat.parallel import ChunkOutcomes, _Pool

    outcomes = ChunkOutcomes((0, 1, 2), "in a test")
    pool = _Pool((0, 1, 2), (), 2, outcomes, 10, lambda *_: None, cpus=1)
    pool.go = {c: threading.Event() for c in (0, 1, 2)}
    pool.ready = [2]  # the shortest chunk loaded first: its slot is not yet due
    pool._grant()
    assert pool.training == set()
    pool.ready.append(1)
    pool._grant()
    assert pool.training == {1}
    assert pool.go[1].is_set()
    assert not pool.go[2].is_set()
    pool.ready.append(0)
    pool._grant()
    assert pool.training == {0, 1}
    outcomes.failed(1, "ended in a test")  # a slot frees: the shortest chunk may go
    pool.training.discard(1)
    pool._grant()
    assert pool.training == {0, 2}
    assert pool.ready == []


def test_gpu_workers_leave_cpus_to_the_process_and_dave2_beside_them() -> None:
    from cam2sim.splat.parallel import worker_cpus

    assert worker_cpus(16, 3, cuda=True) == 4  # three workers, and a share for the rest
    assert worker_cpus(16, 2, cuda=False) == 8  # on the CPU the workers share every core
    assert worker_cpus(2, 3, cuda=True) == 1


def test_a_retried_chunk_waits_for_free_gpu_memory_at_most_its_timeout() -> None:
    from cam2sim.splat.parallel import wait_for_memory

    now = [0.0]
    free = iter([2, 5, 9, 20])  # GiB freed as the processes beside it end

    def sleep(seconds: float) -> None:
        now[0] += seconds

    def clock() -> float:
        return now[0]

    waited = wait_for_memory(lambda: next(free), 16, poll_s=5.0, sleep=sleep, clock=clock)
    assert waited == 15.0  # three polls, then 20 GiB free
    crowded = wait_for_memory(lambda: 1, 16, timeout_s=60.0, poll_s=5.0, sleep=sleep, clock=clock)
    assert crowded == 60.0  # never enough: it goes on at the timeout (and may fail, named)
    assert wait_for_memory(lambda: 32, 16, sleep=sleep, clock=clock) == 0.0


def test_a_crowded_shared_gpu_trains_its_chunks_one_by_one_in_workers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One slot must not mean the interleaved loop, which holds every chunk's Gaussians at once.
    import types

    from cam2sim.core.machine import GPU_SHARERS_VARIABLE
    from cam2sim.splat import train as train_module

    prep = make_prepared_scene(tmp_path / "ws", **TINY)  # type: ignore[arg-type]
    card = types.SimpleNamespace(total_memory=int(79.2 * 2**30))
    monkeypatch.setattr(torch.cuda, "get_device_properties", lambda _device: card)
    monkeypatch.setattr(train_module, "resolve_device", lambda _device: "cuda:0")
    monkeypatch.setattr(train_module, "resolve_backend", lambda _backend, _device: "gsplat")
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "5")
    calls: list[dict[str, object]] = []

    def record(*args: object, **kwargs: object) -> str:
        calls.append({"chunks": args[3], "device": args[4].device, **kwargs})  # type: ignore[attr-defined]
        return "trained in workers"

    monkeypatch.setattr(train_module, "train_chunks_in_processes", record)
    assert train_scene(prep, options=_options()) == "trained in workers"  # type: ignore[comparison-overlap]
    assert calls[0]["in_flight"] == 1
    assert calls[0]["chunks"] == (0, 1, 2)
    assert calls[0]["device"] == "cuda:0"
