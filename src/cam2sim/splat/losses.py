"""Losses and image scores of splat training (torch imported inside the functions only).

- :func:`ssim`: mean SSIM (11x11 Gaussian window, sigma 1.5, "valid" borders) computed with one
  separable, grouped blur of the five SSIM moments stacked together: two convolutions forward
  instead of five 11x11 ones, the same values up to float rounding.
- :func:`photometric_loss`: the masked ``(1 - w) L1 + w (1 - SSIM)`` plus the sky-share terms.
- :func:`apply_affine`, :func:`masked_psnr`: the per-view colour transform, validation PSNR.

Nothing here synchronises the host with the device except :func:`masked_psnr` (a float).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch

__all__ = [
    "SSIM_C1",
    "SSIM_C2",
    "apply_affine",
    "gaussian_window",
    "masked_psnr",
    "photometric_loss",
    "ssim",
    "ssim_reference",
]

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2
_WINDOW = 11
_SIGMA = 1.5
_windows: dict[tuple[str, str], torch.Tensor] = {}


def gaussian_window(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The normalised ``[11]`` Gaussian (sigma 1.5) of SSIM, cached per device and dtype."""
    import torch  # noqa: PLC0415

    key = (str(dtype), str(device))
    window = _windows.get(key)
    if window is None:
        coords = torch.arange(_WINDOW, dtype=torch.float64) - (_WINDOW - 1) / 2
        g = torch.exp(-(coords**2) / (2 * _SIGMA**2))
        window = (g / g.sum()).to(dtype=dtype, device=device)
        _windows[key] = window
    return window


def _blur(stack: torch.Tensor, *, full: bool = False) -> torch.Tensor:
    """Separable Gaussian blur of every channel of ``[1, K, H, W]``.

    "Valid" (``H - 10`` rows out), or with ``full`` the transpose of that (zero-padded,
    ``H + 10`` rows out), which carries gradients back through the valid blur.
    """
    from torch.nn import functional as tnf  # noqa: PLC0415

    k = stack.shape[1]
    g = gaussian_window(stack.dtype, stack.device)
    if full:
        pad = _WINDOW - 1
        stack = tnf.pad(stack, (pad, pad, pad, pad))
    rows = tnf.conv2d(stack, g.view(1, 1, 1, _WINDOW).expand(k, 1, 1, _WINDOW), groups=k)
    return tnf.conv2d(rows, g.view(1, 1, _WINDOW, 1).expand(k, 1, _WINDOW, 1), groups=k)


def _ssim_terms(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """SSIM map and its factors of ``[C, H, W]`` images: ``(S, m_a, m_b, A1, A2, B1, B2)``."""
    import torch  # noqa: PLC0415

    c = a.shape[0]
    blurred = _blur(torch.cat((a, b, a * a, b * b, a * b))[None])[0]
    m_a, m_b, e_aa, e_bb, e_ab = torch.split(blurred, c)
    m_ab = m_a * m_b
    sq_a, sq_b = m_a * m_a, m_b * m_b
    a1 = 2 * m_ab + SSIM_C1
    a2 = 2 * (e_ab - m_ab) + SSIM_C2
    b1 = sq_a + sq_b + SSIM_C1
    b2 = (e_aa - sq_a) + (e_bb - sq_b) + SSIM_C2
    return (a1 * a2) / (b1 * b2), m_a, m_b, a1, a2, b1, b2


def _ssim_function() -> type[torch.autograd.Function]:
    """The autograd function of :func:`ssim` (built on first use: torch is imported lazily)."""
    global _SSIM_FN  # noqa: PLW0603 -- a lazily built class, one per process
    if _SSIM_FN is not None:
        return _SSIM_FN
    import torch  # noqa: PLC0415

    class SSIMFunction(torch.autograd.Function):
        """Mean SSIM with a hand-written gradient for the first image only (one graph node)."""

        @staticmethod
        def forward(ctx: Any, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            s, m_a, m_b, a1, a2, b1, b2 = _ssim_terms(a, b)
            ctx.save_for_backward(a, b, s, m_a, m_b, a1, a2, b1, b2)
            return s.mean()

        @staticmethod
        def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
            a, b, s, m_a, m_b, a1, a2, b1, b2 = ctx.saved_tensors
            g = s * (grad / s.numel())
            # dS/d(blurred moments), as independent variables m_a, E[a^2], E[ab]:
            d_ma = 2 * g * (m_b / a1 - m_b / a2 - m_a / b1 + m_a / b2)
            d_eaa = -g / b2
            d_eab = 2 * g / a2
            back = _blur(torch.cat((d_ma, d_eaa, d_eab))[None], full=True)[0]
            g_ma, g_eaa, g_eab = torch.split(back, a.shape[0])
            return g_ma + 2 * a * g_eaa + b * g_eab, None

    _SSIM_FN = SSIMFunction
    return SSIMFunction


_SSIM_FN: type[torch.autograd.Function] | None = None


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of two ``[H, W, C]`` images in ``[0, 1]`` (11x11 Gaussian window, sigma 1.5).

    The five blurred moments (``x``, ``y``, ``x^2``, ``y^2``, ``xy``) come from one stacked
    ``[1, 5C, H, W]`` tensor blurred by a row then a column convolution (the Gaussian window is
    separable). When only ``x`` needs a gradient (a render against its target), the result is
    one autograd node with a hand-written backward (three stacked moments' gradients blurred
    back, about ten kernels) instead of some thirty recorded operations; otherwise plain
    autograd runs through the same arithmetic.
    """
    import torch  # noqa: PLC0415

    a = x.permute(2, 0, 1)
    b = y.permute(2, 0, 1)
    if torch.is_grad_enabled() and x.requires_grad and not y.requires_grad:
        fn = _ssim_function()
        out: torch.Tensor = fn.apply(a.contiguous(), b.contiguous())  # type: ignore[no-untyped-call]
        return out
    return _ssim_terms(a, b)[0].mean()


def ssim_reference(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """:func:`ssim` with five full 11x11 grouped convolutions (the reference it must match)."""
    import torch  # noqa: PLC0415
    from torch.nn import functional as tnf  # noqa: PLC0415

    c = x.shape[-1]
    g = gaussian_window(x.dtype, x.device)
    window = (g[:, None] * g[None, :]).expand(c, 1, _WINDOW, _WINDOW).contiguous()
    a = x.permute(2, 0, 1)[None]
    b = y.permute(2, 0, 1)[None]

    def blur(t: torch.Tensor) -> torch.Tensor:
        return tnf.conv2d(t, window, groups=c)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    num = (2 * mu_a * mu_b + SSIM_C1) * (2 * cov + SSIM_C2)
    den = (mu_a * mu_a + mu_b * mu_b + SSIM_C1) * (var_a + var_b + SSIM_C2)
    return torch.as_tensor((num / den).mean())


def apply_affine(rgb: torch.Tensor, affine: torch.Tensor) -> torch.Tensor:
    """Apply a ``[3, 4]`` colour transform to ``[..., 3]`` colours."""
    import torch  # noqa: PLC0415

    return torch.addmm(affine[:, 3], rgb.reshape(-1, 3), affine[:, :3].T).view(rgb.shape)


def photometric_loss(
    rgb: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor,
    l1_scale: torch.Tensor,
    ssim_weight: float,
    sky: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    sky_weight: float = 0.0,
) -> torch.Tensor:
    """``(1 - w) L1 + w (1 - SSIM)`` on the pixels where ``mask`` is set, plus the sky terms.

    Args:
        rgb: ``[H, W, 3]`` render (after the colour transform).
        target: ``[H, W, 3]`` image in ``[0, 1]``.
        mask: ``[H, W]`` bool, True = use.
        l1_scale: Scalar tensor ``1 / (3 max(1, mask.sum()))`` (precomputed per view).
        ssim_weight: ``w``; SSIM is taken over the image with excluded pixels copied from
            ``target``.
        sky: ``(sky_share, sky_weights, street_weights)``, each ``[H, W]``: the rendered share
            of sky Gaussians, and weights that average over the used sky pixels and over the
            used other pixels (``pixel_set / max(1, pixel_set.sum())``), or None.
        sky_weight: Weight of the sky terms: the sky share is pulled to 1 on sky pixels and to
            0 on the others.

    Returns:
        The scalar loss; no host-device synchronisation.
    """
    import torch  # noqa: PLC0415

    l1 = (torch.abs(rgb - target).sum(dim=-1) * mask).sum() * l1_scale
    score = ssim(torch.where(mask[..., None], rgb, target), target)
    loss = torch.lerp(l1, 1.0 - score, ssim_weight)
    if sky is not None and sky_weight > 0:
        share, sky_weights, street_weights = sky
        not_sky = ((1.0 - share) * sky_weights).sum()
        not_street = (share * street_weights).sum()
        loss = loss + sky_weight * (not_sky + not_street)
    return loss


def mcmc_regulariser(
    opacity_logits: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_weight: float,
    scale_weight: float,
) -> torch.Tensor:
    """MCMC densification's regularisers: the mean opacity and the mean scale, weighted.

    Gaussians that are not needed fade (and are then moved where others are), and none grows
    larger than the image needs (Kheradmand et al. 2024). Scales in scene units.
    """
    import torch  # noqa: PLC0415

    opacity = torch.sigmoid(opacity_logits).mean()
    return opacity_weight * opacity + scale_weight * torch.exp(log_scales).mean()


def masked_psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float:
    """PSNR (dB) of ``pred`` clamped to ``[0, 1]`` over the pixels where ``mask`` is set."""
    err = ((pred.clamp(0.0, 1.0) - target) ** 2)[mask]
    mse = float(err.mean()) if err.numel() else 0.0
    return 100.0 if mse <= 1e-10 else -10.0 * math.log10(mse)
