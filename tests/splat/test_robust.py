"""The robust weighting leaves blobs of high residual (a transient car) out, not fine texture."""

from __future__ import annotations

import pytest
import torch

from cam2sim.splat.robust import RobustLoss, robust_keep


def _scene(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(96, 128, 3, generator=g)
    render = target + 0.02 * torch.randn(96, 128, 3, generator=g)  # a good fit...
    speckle = torch.rand(96, 128, generator=g) < 0.08  # ...with fine texture it misses
    render[speckle] += 0.5
    render[30:62, 40:80] = 1.0 - target[30:62, 40:80]  # ...and a car that is not in the scene
    return render, target, torch.ones(96, 128, dtype=torch.bool)


def test_a_transient_blob_is_left_out_and_texture_kept() -> None:
    render, target, mask = _scene()
    keep = robust_keep(render, target, mask, RobustLoss(quantile=0.8))
    assert keep[34:58, 44:76].float().mean() < 0.05  # the car's inside: out
    outside = keep.clone()
    outside[28:64, 38:82] = True
    assert outside.float().mean() > 0.99  # everything else, speckles included: in


def test_pixels_outside_the_mask_stay_out_and_nothing_syncs_to_the_host() -> None:
    render, target, mask = _scene(1)
    mask[:, :10] = False
    keep = robust_keep(render, target, mask, RobustLoss(quantile=0.8, patch=8))
    assert not keep[:, :10].any()
    assert keep.dtype == torch.bool
    assert keep.shape == mask.shape


def test_the_weighting_waits_for_its_warm_up_and_checks_its_settings() -> None:
    r = RobustLoss(quantile=0.8, after_steps=100)
    assert not r.active(99)
    assert r.active(100)
    assert not RobustLoss().active(10_000)  # off by default: quantile 0
    with pytest.raises(ValueError, match="quantile"):
        RobustLoss(quantile=1.0)
    with pytest.raises(ValueError, match="patch_inlier"):
        RobustLoss(quantile=0.8, patch_inlier=0.0)
