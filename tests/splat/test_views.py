"""Training views on the device: downsampled copies for coarse-to-fine training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cam2sim.core.errors import StageError
from cam2sim.splat.raster import rasterize
from cam2sim.splat.views import TrainViews, downsample_views, loss_constants

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _views(w: int = 33, h: int = 21, m: int = 3) -> TrainViews:
    rng = np.random.default_rng(0)
    images = torch.from_numpy(rng.integers(0, 256, (m, h, w, 3), dtype=np.uint8))
    masks = torch.ones((m, h, w), dtype=torch.bool)
    masks[:, :, :3] = False  # an ego-hood-like strip on the left
    sky = torch.zeros((m, h, w), dtype=torch.bool)
    sky[:, :7] = True
    k = torch.tensor([[30.0, 0.0, w / 2], [0.0, 30.0, h / 2], [0.0, 0.0, 1.0]])
    return TrainViews(
        frames=(),
        images=images,
        masks=masks,
        sky=sky,
        viewmats=torch.eye(4).repeat(m, 1, 1),
        Ks=k.repeat(m, 1, 1),
        campos=torch.zeros((m, 3)),
        width=w,
        height=h,
    )


def test_downsampled_views_average_blocks_and_scale_the_intrinsics() -> None:
    views = _views()
    half = downsample_views(views, 2, batch=2)
    assert (half.width, half.height) == (16, 10)  # the odd remainder is cut off
    assert half.images.shape == (3, 10, 16, 3)
    assert half.images.dtype == torch.uint8
    block = views.images[1, 4:6, 6:8].float().mean(dim=(0, 1))
    assert torch.allclose(half.images[1, 2, 3].float(), block.round())
    # Column 1 of the coarse image holds full columns 2-3, one of them masked: not used.
    assert not bool(half.masks[0, 0, 1])
    assert bool(half.masks[0, 0, 2])
    assert half.sky is not None
    assert bool(half.sky[0, 2].all())  # rows 4-5: sky
    assert not bool(half.sky[0, 3].any())  # rows 6-7: row 6 sky, row 7 not (a tie: street)
    assert torch.allclose(half.Ks[0, :2], views.Ks[0, :2] / 2)
    assert downsample_views(views, 1) is views
    constants = loss_constants(half)
    assert constants.l1_scale.shape == (3,)
    with pytest.raises(StageError, match="cannot be downsampled"):
        downsample_views(views, 64)


def test_a_coarse_render_matches_the_full_render_averaged() -> None:
    """The halved intrinsics see the scene where the full-size camera does."""
    gen = torch.Generator().manual_seed(1)
    n = 300
    means = torch.rand((n, 3), generator=gen) * torch.tensor([4.0, 3.0, 1.0]) - torch.tensor(
        [2.0, 1.5, -4.0]
    )
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.12)
    opacities = torch.full((n,), 0.9)
    colors = torch.rand((n, 3), generator=gen)
    views = _views(w=64, h=48, m=1)
    half = downsample_views(views, 2)
    args = (means, quats, scales, opacities, colors, views.viewmats)
    full = rasterize(*args, views.Ks, 64, 48, backend="torch").colors[0]
    coarse = rasterize(*args, half.Ks, 32, 24, backend="torch").colors[0]
    pooled = torch.nn.functional.avg_pool2d(full.permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0)
    assert float((coarse - pooled).abs().mean()) < 0.03
    shifted = torch.roll(pooled, 2, dims=1)  # a two-pixel misplacement scores far worse
    assert float((coarse - shifted).abs().mean()) > 2 * float((coarse - pooled).abs().mean())
