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
is gsplat's ``MCMCStrategy`` (relocate faded Gaussians, grow to a cap, position noise; no
resets). As gsplat has it, it draws the Gaussians to copy by opacity alone and keeps no
statistics; with ``mcmc_error_weight`` the draw also follows the accumulated 2-D gradients
(:func:`mcmc_weights`), and the relocation and growth are done here (:func:`relocate` and
:func:`add_copies`, with the paper's opacity and scale split, :func:`relocation_split`).
torch is imported at module level: only the trainer imports this module, inside a function.
"""

from __future__ import annotations

import functools
import logging
import math
from typing import TYPE_CHECKING, Any

import torch

from cam2sim.splat.model import (
    GaussianModel,
    append_copies,
    copy_moments,
    duplicate,
    quench_non_finite,
    remove,
    reset_opacity,
    split,
    zero_moments,
)

if TYPE_CHECKING:
    from cam2sim.splat.raster import RasterOutput
    from cam2sim.splat.train_options import DensifyOptions

__all__ = [
    "MAX_OPACITY_LOGIT",
    "RELOCATION_MAX_COPIES",
    "Densifier",
    "add_copies",
    "mcmc_weights",
    "relocate",
    "relocation_split",
]

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
            "refine_stop_iter": options.refine_stop_at,
            "refine_every": options.refine_every,
        }
        if options.strategy == "mcmc":
            from gsplat.strategy import MCMCStrategy  # noqa: PLC0415

            self.strategy = MCMCStrategy(
                cap_max=options.mcmc_cap, min_opacity=options.prune_opacity, **rhythm
            )
            self.state = {**self.strategy.initialize_state(), "grad2d": None, "count": None}
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
            self._mcmc_post_backward(step, model, optimizers, out, n_street, means_lr)
            return
        if step >= opts.refine_stop_at or out.means2d.grad is None:
            return
        if self.strategy is not None:
            # At the cap no statistics are gathered and nothing grows, but pruning goes on:
            # the opacity resets still come, and what they leave transparent must go.
            growing = len(model) < opts.max_gaussians
            if growing:
                self._accumulate(out, n_street, len(model))
            pause = int(getattr(self.strategy, "pause_refine_after_reset", 0))
            due = step > opts.refine_start and step % opts.refine_every == 0
            if due and step % opts.reset_every >= pause:
                self._gsplat_refine(step, model, optimizers, grow=growing)
        else:
            self._accumulate(out, n_street, len(model))
            due = step > opts.refine_start and step % opts.refine_every == 0
            if due:
                self._refine(step, model, optimizers, generator)
        last = self.last_reset
        if step > 0 and step % opts.reset_every == 0 and (last is None or step <= last):
            reset_opacity(model, optimizers, 2.0 * opts.prune_opacity)

    def _mcmc_post_backward(
        self,
        step: int,
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        out: RasterOutput,
        n_street: int,
        means_lr: float,
    ) -> None:
        """MCMC: relocation and growth when due, position noise on every step.

        ``model.params`` and the optimizers are the street model's alone (the sky never
        moves). At refinement steps the opacity logits are clamped first
        (:data:`MAX_OPACITY_LOGIT`) and broken Gaussians quenched again after.
        """
        opts = self.options
        refining = step > 0 and step % opts.refine_every == 0
        if refining:
            with torch.no_grad():
                model.params["opacities"].clamp_(max=MAX_OPACITY_LOGIT)
        if opts.mcmc_error_weight > 0 or opts.mcmc_inherit_moments:
            self._mcmc_step(step, model, optimizers, out, n_street, means_lr)
        else:
            self.strategy.step_post_backward(
                model.params, optimizers, self.state, step, out.info, lr=means_lr
            )
        if refining:
            # Once more after the relocation: a NaN it made, left until the next refinement,
            # would spoil every step that sees it.
            self._quench(step, model, optimizers)

    def _mcmc_step(
        self,
        step: int,
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        out: RasterOutput,
        n_street: int,
        means_lr: float,
    ) -> None:
        """``MCMCStrategy.step_post_backward``, done here.

        The draw is weighted by the image error (``mcmc_error_weight``), and the copied
        Gaussians keep their moments (``mcmc_inherit_moments``), as the options say.
        """
        from gsplat.strategy.ops import inject_noise_to_position  # noqa: PLC0415

        opts, strategy = self.options, self.strategy
        stop = opts.refine_stop_at
        weighted = opts.mcmc_error_weight > 0
        if weighted and step < stop and out.means2d.grad is not None:
            self._accumulate(out, n_street, len(model))
        due = opts.refine_start < step < stop and step % opts.refine_every == 0
        if due and (not weighted or self.state.get("grad2d") is not None):
            opacity = torch.sigmoid(model.params["opacities"].detach())
            weights = (
                mcmc_weights(
                    model, self.state["grad2d"], self.state["count"], opts.mcmc_error_weight
                )
                if weighted
                else opacity
            )
            dead = opacity <= opts.prune_opacity
            inherit = opts.mcmc_inherit_moments
            relocate(model, optimizers, dead, weights, opts.prune_opacity, inherit_moments=inherit)
            n_new = max(0, min(opts.mcmc_cap, int(1.05 * len(model))) - len(model))
            if n_new:
                add_copies(
                    model,
                    optimizers,
                    n_new,
                    weights if weighted else torch.sigmoid(model.params["opacities"].detach()),
                    opts.prune_opacity,
                    inherit_moments=inherit,
                )
            self.state["grad2d"] = self.state["count"] = None
        inject_noise_to_position(
            params=model.params,
            optimizers=optimizers,
            state={},
            scaler=means_lr * strategy.noise_lr,
        )

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
        self,
        step: int,
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        *,
        grow: bool = True,
    ) -> None:
        """``DefaultStrategy``'s grow and prune on the statistics gathered here.

        ``grow=False`` (the model is at ``max_gaussians``): prune only.
        """
        strategy = self.strategy
        gathered = self.state["grad2d"] is not None
        if grow and not gathered:
            return
        n_before = len(model)
        if grow:
            strategy._grow_gs(model.params, optimizers, self.state, step)  # noqa: SLF001
        strategy._prune_gs(model.params, optimizers, self.state, step)  # noqa: SLF001
        if gathered:
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


def mcmc_weights(
    model: GaussianModel, grad2d: torch.Tensor, count: torch.Tensor, error_weight: float
) -> torch.Tensor:
    """Each Gaussian's weight in MCMC's draw: ``opacity * (1 - e + e * g / mean(g))``.

    ``g`` is the mean 2-D gradient (``grad2d / count``), its mean taken over the Gaussians seen
    since the last refinement; unseen ones have ``g = 0``.
    """
    opacity = torch.sigmoid(model.params["opacities"].detach())
    seen = count > 0
    g = grad2d / count.clamp_min(1.0)
    mean = g.sum() / seen.sum().clamp_min(1)
    relative = g / mean.clamp_min(torch.finfo(g.dtype).tiny)
    return opacity * ((1.0 - error_weight) + error_weight * relative)


def _draw(weights: torch.Tensor, n: int) -> torch.Tensor:
    """``n`` indices drawn with replacement, each with probability proportional to its weight.

    By inverting the cumulative sum, so any number of weights works (``torch.multinomial``
    takes at most 2**24). Non-finite or negative weights count as 0; all zero draws uniformly.
    """
    w = torch.nan_to_num(weights.double(), nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
    w = torch.where(w.sum() > 0, w, torch.ones_like(w))
    cdf = torch.cumsum(w, dim=0)
    u = torch.rand(n, device=w.device, dtype=w.dtype) * cdf[-1]
    return torch.searchsorted(cdf, u, right=True).clamp_max(len(w) - 1)


MAX_OPACITY_LOGIT = 15.0
"""MCMC clamps opacity logits to this before relocating (opacity 1 - 3e-7, not 1).

gsplat's relocation splits an opacity among N copies in float32 with an alternating sum of
binomial coefficients (up to 1e14). For an opacity that rounds to exactly 1 (logit above
about 16.6) nothing damps the terms, and from about 35 copies the sum cancels to nothing or
below: the copies' scales come out negative, their logarithm NaN. Just below 1 the sum is
exact to float32 for any number of copies (docs/benchmarks.md, 2026-11-27).
"""

RELOCATION_MAX_COPIES = 51
"""Copies of one Gaussian the relocation formula counts at most (gsplat's table size)."""


@functools.lru_cache(maxsize=4)
def _relocation_table(device: str) -> torch.Tensor:
    """Row ``N-1``: ``C(i-1, k) (-1)**k / sqrt(k+1)`` summed over ``i = 1..N``, for each ``k``."""
    n_max = RELOCATION_MAX_COPIES
    coef = torch.tensor(
        [
            [
                math.comb(i, k) * (-1.0) ** k / math.sqrt(k + 1) if k <= i else 0.0
                for k in range(n_max)
            ]
            for i in range(n_max)
        ],
        dtype=torch.float64,
        device=device,
    )
    return torch.cumsum(coef, dim=0)


def relocation_split(
    opacity: torch.Tensor, scales: torch.Tensor, copies: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The opacity and scales of each of ``copies`` Gaussians that together draw what one drew.

    Kheradmand et al. 2024, eq. 9 (what gsplat's relocation kernel computes). ``opacity``
    ``[M]``, ``scales`` ``[M, 3]``, ``copies`` ``[M]`` (counting the original; at most
    :data:`RELOCATION_MAX_COPIES`). The new opacity is ``1 - (1 - o) ** (1 / N)``, so N
    layers of it are as opaque as the one; the scales shrink by
    ``o / sum_{i=1..N} sum_{k<i} C(i-1, k) (-1)**k o_new**(k+1) / sqrt(k+1)``, so the summed
    footprint keeps the one's. Vectorised, in float64 (the alternating sum cancels).
    """
    n_max = RELOCATION_MAX_COPIES
    dev = opacity.device
    per_n = _relocation_table(str(dev)).to(dev)
    ks = torch.arange(n_max, dtype=torch.float64, device=dev)[None, :]
    n = copies.clamp(1, n_max).long()
    o = opacity.double()
    new_o = 1.0 - (1.0 - o) ** (1.0 / n.double())
    powers = new_o[:, None] ** (ks + 1)
    denom = (per_n[n - 1] * powers).sum(dim=1)
    factor = (o / denom).to(scales.dtype)
    return new_o.to(opacity.dtype), scales * factor[:, None]


def _split_among_copies(model: GaussianModel, sampled: torch.Tensor, min_opacity: float) -> None:
    """Give each drawn Gaussian the opacity and scales that it and its copies share.

    ``sampled`` lists each copy's original (repeats: several copies); in place, on ``model``.
    """
    params = model.params
    new_opacity, new_scales = relocation_split(
        torch.sigmoid(params["opacities"].detach()[sampled]),
        torch.exp(params["scales"].detach()[sampled]),
        torch.bincount(sampled, minlength=len(model))[sampled] + 1,
    )
    eps = torch.finfo(torch.float32).eps
    new_opacity = new_opacity.clamp(min=min_opacity, max=1.0 - eps)
    with torch.no_grad():
        params["opacities"][sampled] = torch.logit(new_opacity)
        params["scales"][sampled] = torch.log(new_scales)


def relocate(
    model: GaussianModel,
    optimizers: dict[str, torch.optim.Optimizer],
    dead: torch.Tensor,
    weights: torch.Tensor,
    min_opacity: float,
    *,
    inherit_moments: bool = False,
) -> int:
    """Move the ``dead`` Gaussians onto live ones drawn by ``weights``; return how many.

    Each drawn Gaussian and the dead ones moved onto it share its opacity and scale
    (:func:`_split_among_copies`); their Adam moments restart at zero, or with
    ``inherit_moments`` the drawn ones keep theirs and the moved ones take them.
    """
    dead_rows = dead.nonzero(as_tuple=True)[0]
    alive_rows = (~dead).nonzero(as_tuple=True)[0]
    n = len(dead_rows)
    if n == 0 or len(alive_rows) == 0:
        return 0
    sampled = alive_rows[_draw(weights[alive_rows], n)]
    _split_among_copies(model, sampled, min_opacity)
    with torch.no_grad():
        for name, p in model.params.items():
            p[dead_rows] = p[sampled]
            opt = optimizers.get(name)
            if opt is None:
                continue
            state = opt.state.get(p, {})
            if inherit_moments:
                copy_moments(state, p, sampled, dead_rows)
            else:
                zero_moments(state, p, sampled)
                zero_moments(state, p, dead_rows)
    return n


def add_copies(
    model: GaussianModel,
    optimizers: dict[str, torch.optim.Optimizer],
    n: int,
    weights: torch.Tensor,
    min_opacity: float,
    *,
    inherit_moments: bool = False,
) -> None:
    """Grow the model by ``n`` copies of Gaussians drawn by ``weights`` (MCMC's growth).

    The drawn Gaussians and their copies restart their Adam moments at zero, or with
    ``inherit_moments`` keep the drawn ones'.
    """
    sampled = _draw(weights, n)
    _split_among_copies(model, sampled, min_opacity)
    if not inherit_moments:
        with torch.no_grad():
            for name, p in model.params.items():
                opt = optimizers.get(name)
                if opt is not None:
                    zero_moments(opt.state.get(p, {}), p, sampled)
    append_copies(model, optimizers, sampled, inherit_moments=inherit_moments)
