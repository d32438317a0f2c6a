"""One Adam step for all of a chunk's optimizers at once (torch imported inside functions only).

Training keeps one ``torch.optim.Adam`` per parameter (gsplat's densification replaces the
parameters and their optimizer state by name), about eight per chunk. Calling each one's
``step()`` costs ~0.15 ms of Python per call, more than the GPU needs for the update itself.
:func:`adam_step` runs the same update for all of them with one step-counter increment and one
``torch._fused_adam_`` call per distinct ``(lr, betas, eps)``: the arithmetic of
``Adam(fused=True).step()``, with the optimizers' own state tensors (``step``, ``exp_avg``,
``exp_avg_sq``), so densification and checkpoints see the usual layout. On the CPU as on CUDA:
there torch's fused kernel took the optimizer phase of a 40,000-Gaussian step from 8 to 2 ms
(2 cores; ``benchmarks/splat_cpu_step.py``), against the unfused per-tensor loop.

With ``finite=True`` (the trainer's setting) a step whose gradients hold a NaN or inf value is
skipped, as mixed-precision training skips one. One such value, stepped into a Gaussian, makes
it draw NaN into every pixel it covers, and the next backward pass makes NaN of every Gaussian
in those pixels: on 2026-11-27 three of about thirty 30,000-step MCMC runs on real frames
(antialiased) lost most or all of their street model that way, even with the densifier making
NaN Gaussians transparent at every refinement: that guard turned each broken Gaussian into a
zero quaternion, NaN in gsplat's kernels, so it went on drawing NaN (fixed in
:func:`cam2sim.splat.model.make_transparent`; one source of the first NaN, gsplat's relocation
at an opacity of 1, is closed in :mod:`cam2sim.splat.densify`). The check is one fused
reduction a step, and :func:`adam_step` counts the steps it skipped.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    import torch

    # (params, grads, exp_avgs, exp_avg_sqs, step counters) of one fused Adam call
    Bucket = tuple[
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
        list[torch.Tensor],
    ]
    BucketKey = tuple[float, float, float, float, torch.device]  # lr, beta1, beta2, eps, device

__all__ = ["adam_step"]


def _non_finite(grads: list[torch.Tensor]) -> torch.Tensor:
    """1.0 (float32, on the gradients' device) when a value of ``grads`` is NaN or inf, else 0.0.

    No host synchronisation. On CUDA one fused reduction (each gradient's largest magnitude);
    on the CPU, where that reduction is slow (9 ms for 100,000 Gaussians on 2 cores), each
    gradient's smallest and largest value (0.8 ms; both are NaN where a value is).
    """
    import torch  # noqa: PLC0415

    if grads[0].device.type == "cuda":
        peaks = list(torch._foreach_norm(grads, ord=float("inf")))  # noqa: SLF001
    else:
        peaks = [v for g in grads for v in torch.aminmax(g)]
    return (~torch.isfinite(torch.stack(peaks))).any().to(torch.float32)


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


def _step_alone(opt: torch.optim.Optimizer, found: dict[torch.device, torch.Tensor] | None) -> None:
    """Step an optimizer :func:`adam_step` cannot fuse; with ``found``, NaN and inf as 0.

    ``found`` is :func:`_found_inf`'s flags. On the CPU the flag is read and the gradients
    are rewritten only when it is set (reading costs nothing there); elsewhere they are
    rewritten every time, to keep the step free of host synchronisations.
    """
    import torch  # noqa: PLC0415

    if found is not None:
        for group in opt.param_groups:
            for p in group["params"]:
                g = p.grad
                if g is None:
                    continue
                flag = found.get(g.device)
                if g.device.type == "cpu" and (flag is None or not bool(flag)):
                    continue
                torch.nan_to_num_(g, nan=0.0, posinf=0.0, neginf=0.0)
    opt.step()
    opt.zero_grad(set_to_none=True)


def _add_to_buckets(
    opt: torch.optim.Optimizer, buckets: dict[BucketKey, Bucket], stepped: list[torch.Tensor]
) -> None:
    """File each parameter of ``opt`` that has a gradient under its fused call's key."""
    import torch  # noqa: PLC0415

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
            key = (float(group["lr"]), float(beta1), float(beta2), float(group["eps"]), p.device)
            bucket = buckets.setdefault(key, ([], [], [], [], []))
            bucket[0].append(p)
            bucket[1].append(p.grad)
            bucket[2].append(state["exp_avg"])
            bucket[3].append(state["exp_avg_sq"])
            bucket[4].append(state["step"])
            stepped.append(p)


def _found_inf(
    buckets: dict[BucketKey, Bucket],
    alone: list[torch.optim.Optimizer],
    counter: torch.Tensor | None,
) -> dict[torch.device, torch.Tensor]:
    """Per device, 1.0 when a gradient holds NaN or inf; count such a step in ``counter``."""
    import torch  # noqa: PLC0415

    by_device: dict[torch.device, list[torch.Tensor]] = {}
    for key, bucket in buckets.items():
        by_device.setdefault(key[4], []).extend(g for g in bucket[1] if g.numel())
    for opt in alone:
        for group in opt.param_groups:
            for p in group["params"]:
                if p.grad is not None and p.grad.numel():
                    by_device.setdefault(p.grad.device, []).append(p.grad)
    found = {dev: _non_finite(grads) for dev, grads in by_device.items() if grads}
    if counter is not None and found:
        flags = [f.to(counter.device) for f in found.values()]
        bad = flags[0] if len(flags) == 1 else torch.stack(flags).amax()
        counter += bad.to(counter.dtype)
    return found


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
    skipped, as ``Adam.step`` does.

    With ``finite`` a step whose gradients hold a NaN or inf value leaves the fused optimizers'
    parameters and moments as they were (their ``found_inf``, as mixed-precision training
    skips a step), the other optimizers (those it cannot fuse: the poses', with weight decay) get
    those values as zero, and
    ``non_finite_steps`` (a scalar tensor, if given) counts the step; all without a host
    synchronisation.
    """
    import torch  # noqa: PLC0415

    buckets: dict[BucketKey, Bucket] = {}
    stepped: list[torch.Tensor] = []
    alone: list[torch.optim.Optimizer] = []
    for opt in optimizers:
        if _fast(opt):
            _add_to_buckets(opt, buckets, stepped)
        else:
            alone.append(opt)
    found = _found_inf(buckets, alone, non_finite_steps) if finite else {}
    for opt in alone:
        _step_alone(opt, found if finite else None)
    steps: dict[torch.device, list[torch.Tensor]] = {}
    for key, bucket in buckets.items():
        steps.setdefault(key[4], []).extend(bucket[4])
    with torch.no_grad():
        for counters in steps.values():
            torch._foreach_add_(counters, 1)
        for (lr, beta1, beta2, eps, device), bucket in buckets.items():
            params, grads, avgs, avg_sqs, counts = bucket
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
                found_inf=found.get(device),
            )
        for device, counters in steps.items():
            if device in found:  # a skipped step does not count, as in torch's own Adam
                torch._foreach_sub_(counters, [found[device]] * len(counters))
    for p in stepped:
        p.grad = None
