"""One Adam step for all of a chunk's optimizers at once (torch imported inside functions only).

Training keeps one ``torch.optim.Adam`` per parameter (gsplat's densification replaces the
parameters and their optimizer state by name), about eight per chunk. Calling each one's
``step()`` costs ~0.15 ms of Python per call, more than the GPU needs for the update itself.
:func:`adam_step` runs the same update for all of them with one step-counter increment and one
``torch._fused_adam_`` call per distinct ``(lr, betas, eps)``: the arithmetic of
``Adam(fused=True).step()``, with the optimizers' own state tensors (``step``, ``exp_avg``,
``exp_avg_sq``), so densification and checkpoints see the usual layout.

Non-finite gradient values (NaN, inf) are set to zero before the update (``finite=True``, the
trainer's setting). One such value, stepped into a Gaussian, makes it draw NaN into every pixel
it covers, and the next backward pass makes NaN of every Gaussian in those pixels, of the
per-view colour transforms and the sky: on 2026-11-27 four of about thirty 30,000-step MCMC
runs on real frames (antialiased) lost their whole street model that way. gsplat's
antialiasing term divides by its compensation plus 1e-6 in the backward pass, so a thin
Gaussian's gradient is amplified about 500,000 times, the likely source. Zeroing costs one
in-place pass over the gradients, and :func:`adam_step` counts the steps it happened on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    import torch

__all__ = ["adam_step"]


def _zero_non_finite(
    optimizers: Sequence[torch.optim.Optimizer], counter: torch.Tensor | None
) -> None:
    """Set the non-finite values of every gradient to zero; count the step in ``counter``."""
    import torch  # noqa: PLC0415

    grads = [
        p.grad
        for opt in optimizers
        for group in opt.param_groups
        for p in group["params"]
        if p.grad is not None and p.grad.numel()
    ]
    if not grads:
        return
    if counter is not None:
        # The largest magnitude is finite unless a value is not: one fused reduction.
        peaks = torch._foreach_norm(grads, ord=float("inf"))  # noqa: SLF001
        bad = (~torch.isfinite(torch.stack([v.to(counter.device) for v in peaks]))).any()
        counter += bad.to(counter.dtype)
    for g in grads:
        torch.nan_to_num_(g, nan=0.0, posinf=0.0, neginf=0.0)


def _fast(opt: torch.optim.Optimizer) -> bool:
    import torch  # noqa: PLC0415

    if type(opt) is not torch.optim.Adam:
        return False
    return all(
        g.get("fused")
        and not g.get("amsgrad")
        and not g.get("maximize")
        and not g.get("capturable")
        and not g.get("differentiable")
        and not g.get("decoupled_weight_decay", False)
        and g.get("weight_decay", 0.0) == 0.0
        and not isinstance(g["lr"], torch.Tensor)
        for g in opt.param_groups
    )


def adam_step(
    optimizers: Sequence[torch.optim.Optimizer],
    *,
    finite: bool = False,
    non_finite_steps: torch.Tensor | None = None,
) -> None:
    """Step every optimizer of ``optimizers``, then set their gradients to None.

    Fused, plain Adam optimizers (``Adam(..., fused=True)`` without amsgrad, weight decay,
    maximize, capturable or tensor learning rates) are stepped together as described in the
    module doc; any other optimizer runs its own ``step()``. Parameters without a gradient are
    skipped, as ``Adam.step`` does. With ``finite`` every non-finite gradient value is set to
    zero first, and ``non_finite_steps`` (a scalar tensor on the gradients' device, if given)
    is incremented when there was one, without a host synchronisation.
    """
    import torch  # noqa: PLC0415

    if finite:
        _zero_non_finite(optimizers, non_finite_steps)

    Bucket = tuple[
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
    ]
    buckets: dict[tuple[float, float, float, float, torch.device], Bucket] = {}
    steps: dict[torch.device, list[torch.Tensor]] = {}
    stepped: list[torch.Tensor] = []
    for opt in optimizers:
        if not _fast(opt):
            opt.step()
            opt.zero_grad(set_to_none=True)
            continue
        for group in opt.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = opt.state[p]
                if not state:  # as Adam._init_group does for fused Adam
                    state["step"] = torch.zeros((), dtype=torch.float32, device=p.device)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                key = (
                    float(group["lr"]),
                    float(beta1),
                    float(beta2),
                    float(group["eps"]),
                    p.device,
                )
                bucket = buckets.setdefault(key, ([], [], [], [], []))
                bucket[0].append(p)
                bucket[1].append(p.grad)
                bucket[2].append(state["exp_avg"])
                bucket[3].append(state["exp_avg_sq"])
                bucket[4].append(state["step"])
                steps.setdefault(p.device, []).append(state["step"])
                stepped.append(p)
    with torch.no_grad():
        for counters in steps.values():
            torch._foreach_add_(counters, 1)
        for (lr, beta1, beta2, eps, _), (params, grads, avgs, avg_sqs, counts) in buckets.items():
            torch._fused_adam_(
                params,
                grads,
                avgs,
                avg_sqs,
                [],
                counts,
                amsgrad=False,
                lr=lr,
                beta1=beta1,
                beta2=beta2,
                weight_decay=0.0,
                eps=eps,
                maximize=False,
                grad_scale=None,
                found_inf=None,
            )
    for p in stepped:
        p.grad = None
