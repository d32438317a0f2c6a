"""Densification rules of splat training: clone, split and prune Gaussians, reset opacities.

:class:`Densifier` follows the 3DGS rules (as gsplat's ``DefaultStrategy``): 2-D gradients of the
projected centres are accumulated per Gaussian after every ``backward()``; every
``refine_every`` steps Gaussians with a high mean gradient are cloned (small ones) or split (large
ones), transparent and (after the first reset) huge ones are pruned. Two variants:

- gsplat (``use_gsplat=True``): the surgery is ``DefaultStrategy``'s own (``_grow_gs`` and
  ``_prune_gs`` of the pinned gsplat 1.5.3), while the statistics are accumulated here as dense
  sums, the same values as the strategy's ``index_add_`` over ``torch.where(radii > 0)`` without
  its host-device synchronisation on every step;
- simple: the same rules with :mod:`cam2sim.splat.model`'s operations (any device).

With ``absgrad`` the statistics are the absolute per-pixel gradients that gsplat accumulates
into ``means2d.absgrad`` (AbsGS), not the gradients' norm: textured surfaces whose per-pixel
gradients cancel out still grow Gaussians. With ``pixel_weighted`` each view's gradient counts by
the Gaussian's screen footprint in that view (Pixel-GS), optionally damped near the camera.

Both reset opacities themselves (gsplat 1.5.3's strategy never does). A third, ``strategy="mcmc"``,
is gsplat's ``MCMCStrategy`` as it is (relocate faded Gaussians, grow to a cap, position noise;
no resets, no statistics). torch is imported at module level: only the trainer imports this
module, inside a function.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import torch

from cam2sim.splat.model import (
    GaussianModel,
    duplicate,
    quench_non_finite,
    remove,
    reset_opacity,
    split,
)

if TYPE_CHECKING:
    from cam2sim.splat.raster import RasterOutput
    from cam2sim.splat.train_options import DensifyOptions

__all__ = ["Densifier"]

_log = logging.getLogger(__name__)


class Densifier:
    """Clone/split/prune by accumulated 2-D gradients, and reset opacities (see the module doc)."""

    def __init__(
        self,
        options: DensifyOptions,
        scene_scale: float,
        *,
        use_gsplat: bool,
        max_steps: int | None = None,
    ) -> None:
        self.options = options
        self.n_non_finite = 0
        """Gaussians found with non-finite parameters and made transparent, in all."""
        self.last_reset: int | None = None
        if max_steps is not None:
            self.end_at(max_steps)
        self.scene_scale = scene_scale
        self.strategy: Any = None  # Any: gsplat ships no type information
        self.state: dict[str, Any] = {"grad2d": None, "count": None}
        self._grad_scale: tuple[tuple[Any, ...], torch.Tensor] | None = None
        # When the strategies refine: the same rhythm for both of gsplat's.
        rhythm = {
            "refine_start_iter": options.refine_start,
            "refine_stop_iter": options.refine_stop,
            "refine_every": options.refine_every,
        }
        if options.strategy == "mcmc":
            from gsplat.strategy import MCMCStrategy  # noqa: PLC0415

            self.strategy = MCMCStrategy(
                cap_max=options.mcmc_cap, min_opacity=options.prune_opacity, **rhythm
            )
            self.state = self.strategy.initialize_state()
        elif use_gsplat:
            from gsplat.strategy import DefaultStrategy  # noqa: PLC0415

            self.strategy = DefaultStrategy(
                prune_opa=options.prune_opacity,
                grow_grad2d=options.grow_grad2d,
                grow_scale3d=options.grow_scale3d,
                prune_scale3d=options.prune_scale3d,
                reset_every=options.reset_every,
                absgrad=options.absgrad,
                **rhythm,
            )
            self.state = self.strategy.initialize_state(scene_scale=scene_scale)

    def end_at(self, max_steps: int) -> None:
        """Training ends at ``max_steps``: no opacity reset within ``reset_every`` steps of it.

        The model needs about that long to recover from a reset.
        """
        self.last_reset = max_steps - self.options.reset_every

    def post_backward(
        self,
        step: int,
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        out: RasterOutput,
        n_street: int,
        generator: torch.Generator,
        means_lr: float = 0.0,
    ) -> None:
        """Update statistics after ``backward()`` and refine when the step is due.

        ``means_lr`` (the means' learning rate of this step) scales MCMC's position noise.
        """
        opts = self.options
        if step > 0 and step % opts.refine_every == 0:
            self._quench(step, model, optimizers)
        if opts.strategy == "mcmc":
            # Relocation and growth when due, position noise on every step; model.params and
            # the optimizers are the street model's alone (the sky never moves).
            self.strategy.step_post_backward(
                model.params, optimizers, self.state, step, out.info, lr=means_lr
            )
            return
        if step >= opts.refine_stop or out.means2d.grad is None:
            return
        if self.strategy is not None:
            if len(model) < opts.max_gaussians:
                self._accumulate(out, n_street, len(model))
                pause = int(getattr(self.strategy, "pause_refine_after_reset", 0))
                due = step > opts.refine_start and step % opts.refine_every == 0
                if due and step % opts.reset_every >= pause:
                    self._gsplat_refine(step, model, optimizers)
        else:
            self._accumulate(out, n_street, len(model))
            due = step > opts.refine_start and step % opts.refine_every == 0
            if due:
                self._refine(step, model, optimizers, generator)
        last = self.last_reset
        if step > 0 and step % opts.reset_every == 0 and (last is None or step <= last):
            reset_opacity(model, optimizers, 2.0 * opts.prune_opacity)

    def _quench(
        self, step: int, model: GaussianModel, optimizers: dict[str, torch.optim.Optimizer]
    ) -> None:
        """Make Gaussians with NaN or inf parameters transparent before they are refined."""
        n_bad = quench_non_finite(model, optimizers)
        if n_bad:
            self.n_non_finite += n_bad
            _log.warning(
                "step %d: %d Gaussians had non-finite parameters (NaN or inf); made them "
                "transparent, to be pruned or relocated",
                step,
                n_bad,
            )

    def _accumulate(self, out: RasterOutput, n_street: int, n: int) -> None:
        """Add this step's normalised 2-D gradient norms and visibility counts (no sync)."""
        # gsplat adds ``absgrad`` to means2d in its backward when rasterized with absgrad=True.
        source = getattr(out.means2d, "absgrad", None) if self.options.absgrad else out.means2d.grad
        assert source is not None
        grads = source[:, :n_street]
        n_cameras = out.info["n_cameras"]
        key = (out.info["width"], out.info["height"], n_cameras, grads.device, grads.dtype)
        if self._grad_scale is None or self._grad_scale[0] != key:
            scale = torch.tensor(
                [out.info["width"] / 2.0 * n_cameras, out.info["height"] / 2.0 * n_cameras],
                dtype=grads.dtype,
                device=grads.device,
            )
            self._grad_scale = (key, scale)
        radii = out.radii[:, :n_street]
        if self.state["grad2d"] is None:
            self.state["grad2d"] = torch.zeros(n, device=grads.device)
            self.state["count"] = torch.zeros(n, device=grads.device)
        norms = torch.linalg.vector_norm(grads * self._grad_scale[1], dim=-1)
        # Each view's weight: 1 where the Gaussian is seen, or with pixel_weighted its screen
        # box's area (radii are 0 where culled); _grow_gs and _refine take the mean
        # sum(w * g) / sum(w) from the two sums.
        if self.options.pixel_weighted:
            weight = radii.to(norms.dtype).prod(dim=-1)
            if self.options.near_damping > 0:
                near = self.options.near_damping * self.scene_scale
                depth = out.depths[:, :n_street].to(norms.dtype)
                norms = norms * (depth / near).clamp(0.0, 1.0) ** 2
        else:
            weight = (radii > 0).all(dim=-1).to(norms.dtype)
        self.state["grad2d"] += (norms * weight).sum(dim=0)
        self.state["count"] += weight.sum(dim=0)

    def _gsplat_refine(
        self, step: int, model: GaussianModel, optimizers: dict[str, torch.optim.Optimizer]
    ) -> None:
        """``DefaultStrategy``'s grow and prune on the statistics gathered here."""
        strategy = self.strategy
        if self.state["grad2d"] is None:
            return
        n_before = len(model)
        strategy._grow_gs(model.params, optimizers, self.state, step)  # noqa: SLF001
        strategy._prune_gs(model.params, optimizers, self.state, step)  # noqa: SLF001
        self.state["grad2d"].zero_()
        self.state["count"].zero_()
        if getattr(strategy, "refine_scale2d_stop_iter", 0) > 0:
            self.state["radii"].zero_()
        _log.debug("step %d: %d -> %d Gaussians", step, n_before, len(model))

    def _refine(
        self,
        step: int,
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        generator: torch.Generator,
    ) -> None:
        opts = self.options
        grad2d, count = self.state["grad2d"], self.state["count"]
        if grad2d is None:
            return
        n_before = len(model)
        if n_before < opts.max_gaussians:
            high = grad2d / count.clamp_min(1.0) > opts.grow_grad2d
            max_scale = torch.exp(model.params["scales"].detach()).max(dim=-1).values
            small = max_scale <= opts.grow_scale3d * self.scene_scale
            clone = high & small
            if clone.any():
                duplicate(model, optimizers, clone)
            grown = high & ~small
            pad = torch.zeros(int(clone.sum()), dtype=torch.bool, device=grown.device)
            grown = torch.cat((grown, pad))
            if grown.any():
                split(model, optimizers, grown, generator=generator)
        prune = torch.sigmoid(model.params["opacities"].detach()) < opts.prune_opacity
        if step > opts.reset_every:
            max_scale = torch.exp(model.params["scales"].detach()).max(dim=-1).values
            prune |= max_scale > opts.prune_scale3d * self.scene_scale
        if prune.any():
            remove(model, optimizers, prune)
        _log.debug("step %d: %d -> %d Gaussians", step, n_before, len(model))
        self.state["grad2d"] = None
        self.state["count"] = None
