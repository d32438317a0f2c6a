"""Densifying to ``max_gaussians`` with gsplat's ``DefaultStrategy``: no growth, pruning goes on."""

from __future__ import annotations

import sys
import types
from dataclasses import dataclass, field

import pytest

pytest.importorskip("torch")

import torch
from gaussian_fixtures import model_and_adam, one_view_output

from cam2sim.splat.densify import Densifier
from cam2sim.splat.train import DensifyOptions

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@dataclass
class _DefaultStrategyStandIn:
    """Records which of gsplat's refinement operations ran, and prunes the transparent ones."""

    prune_opa: float
    grow_grad2d: float
    grow_scale3d: float
    prune_scale3d: float
    reset_every: int
    absgrad: bool
    refine_start_iter: int
    refine_stop_iter: int
    refine_every: int
    calls: list[tuple[str, int]] = field(default_factory=list)

    def initialize_state(self, scene_scale: float) -> dict[str, object]:
        return {"grad2d": None, "count": None, "scene_scale": scene_scale}

    def _grow_gs(self, params, optimizers, state, step) -> None:
        self.calls.append(("grow", step))

    def _prune_gs(self, params, optimizers, state, step) -> None:
        self.calls.append(("prune", step))
        keep = torch.sigmoid(params["opacities"].detach()) >= self.prune_opa
        for name in list(params):
            params[name] = torch.nn.Parameter(params[name].detach()[keep])
        for key in ("grad2d", "count"):
            if state[key] is not None:
                state[key] = state[key][keep]


@pytest.fixture
def default_strategy(monkeypatch: pytest.MonkeyPatch) -> None:
    strategy = types.ModuleType("gsplat.strategy")
    strategy.DefaultStrategy = _DefaultStrategyStandIn  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "gsplat", types.ModuleType("gsplat"))
    monkeypatch.setitem(sys.modules, "gsplat.strategy", strategy)


@pytest.mark.usefixtures("default_strategy")
@pytest.mark.parametrize("cap", [10, 100])
def test_at_the_cap_pruning_goes_on_and_nothing_grows(cap: int) -> None:
    options = DensifyOptions(refine_start=0, refine_every=5, reset_every=1000, max_gaussians=cap)
    densifier = Densifier(options, scene_scale=1.0, use_gsplat=True)
    model, opts = model_and_adam(20)
    with torch.no_grad():
        model.params["opacities"][:3] = -12.0  # three transparent ones
    for step in range(1, 6):
        out = one_view_output(len(model), torch.ones(1, len(model), 2))
        densifier.post_backward(step, model, opts, out, len(model), torch.Generator())
    calls = densifier.strategy.calls
    if cap > 20:  # under the cap: statistics gathered, grown and pruned
        assert calls == [("grow", 5), ("prune", 5)]
        assert densifier.state["count"] is not None
        assert densifier.state["count"].shape == (17,)
    else:  # at the cap: no statistics, no growth, but the transparent ones still go
        assert calls == [("prune", 5)]
        assert densifier.state["grad2d"] is None
    assert len(model) == 17
