"""TrainState: a chunk's progress, its best score, its time share and the cap fitted to it."""

from __future__ import annotations

from cam2sim.splat.state import TrainState


def test_the_best_score_and_the_stop() -> None:
    state = TrainState(cap=100)
    assert state.best is None
    state.history += [(10, 20.0, 0.5), (20, 22.5, 0.6), (30, 21.0, 0.6)]
    assert state.best == 22.5
    assert not state.done
    state.stop("plateau")
    assert (state.done, state.stopped) == (True, "plateau")


def test_the_cap_moves_to_where_the_time_share_runs_out() -> None:
    # 10 s for the chunk, less the last validation's 1 s; 100 steps took 2 s: 7 s left at 50
    # steps a second is 350 more steps, a cap at 450.
    state = TrainState(cap=1000, time_share=10.0, step=100, val_seconds=1.0)
    assert not state.out_of_time(8.0)
    assert state.out_of_time(9.0)
    assert state.fit_cap(2.0, max_steps=1000) == 450
    assert (state.cap, state.pace_mark) == (450, (100, 2.0))
    state.step = 200  # 100 more steps in 2 more seconds: the same pace, the cap stays
    assert state.fit_cap(4.0, max_steps=1000) is None
    fresh = TrainState(cap=1000, time_share=10.0, step=100, val_seconds=1.0)
    assert fresh.fit_cap(2.0, max_steps=300) == 300  # never past max_steps
    assert TrainState(cap=50, time_share=1e6, step=10).fit_cap(0.1, max_steps=50) is None
