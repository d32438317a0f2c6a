"""Training of one chunk's Gaussian-splat model: :class:`ChunkTrainer`, one step at a time.

:mod:`cam2sim.splat.train` runs it for every chunk of a scene (in turn, or in worker
processes). Per chunk:

- **Initialisation** (:func:`cam2sim.splat.model.seed_models`): one Gaussian per point of
  ``points.npz`` that a training view sees, plus fixed-position sky Gaussians on a far sphere.
- **Loss**, on pixels whose mask is 255: ``(1 - w) L1 + w (1 - SSIM)`` with ``w = ssim_weight``
  (SSIM over an image where excluded pixels are copied from the target). With sky masks, the
  share of each pixel drawn by sky Gaussians (a fourth rendered channel) is pulled to 1 on sky
  pixels and to 0 elsewhere (``sky_weight``): street Gaussians cannot float in the sky, and sky
  Gaussians cannot paint the street.
- **Appearance**: a per-view affine colour transform (3x3 + bias, identity at first, own small
  learning rate) applied to the render before the loss.
- **Densification** (:class:`cam2sim.splat.densify.Densifier`): gsplat's ``MCMCStrategy`` for
  gsplat runs of at least ``MCMC_MIN_STEPS`` steps without a time budget (with opacity 0.5 at the
  start, opacity and scale regularisers, no sky-share term; :func:`resolve_options`), else
  gsplat's ``DefaultStrategy`` with the gsplat backend and a simple densifier of the same rules
  on the torch one; opacities are reset here every ``reset_every`` steps (not with MCMC), as
  gsplat 1.5.3's strategy never does it.
- **Stopping**: every ``val_every`` steps the PSNR and SSIM of up to ``n_val_views`` training
  views spread along the chunk (held-in validation) are measured. After ``min_steps``, training
  stops on a plateau: when the least-squares trend of the last ``patience + 1`` validations
  rises by less than ``min_gain_db`` dB and less than ``min_gain_ssim`` SSIM per 1,000 steps;
  else at ``max_steps``. A trend over several validations, and SSIM beside PSNR, keep one noisy
  validation (PSNR swings of ±0.5 dB between checks are common) from ending training while the
  fine structure still improves.
- **Time budget** (``time_budget_s``, optional): the chunks of one call share the seconds, each
  getting the budget divided by the rounds in which they train (:func:`time_share`), or each
  chunk the whole budget with ``budget_per_chunk`` (a longer route trains longer). At every
  validation a chunk measures its pace over the last interval and moves its step cap to the step
  its share runs out at (never above ``max_steps``): the means' learning rate is re-aimed to
  reach its final value there and no opacity reset falls within ``reset_every`` steps of it. One
  validation's time is kept back for the last one: a chunk stops (``stopped == "time"``) after
  the step at which a validation as long as the previous would overrun its share, scoring it.

torch and gsplat are imported inside functions only.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cam2sim.core.errors import StageError
from cam2sim.splat.losses import (
    apply_affine,
    masked_psnr,
    mcmc_regulariser,
    photometric_loss,
    ssim,
)
from cam2sim.splat.optim import adam_step
from cam2sim.splat.pose_refine import (
    corrected_pose,
    correction_sizes,
    remove_common_motion,
    se3_exp,
)
from cam2sim.splat.profiling import PhaseTimer, profiling_requested
from cam2sim.splat.raster import rasterize
from cam2sim.splat.robust import robust_keep
from cam2sim.splat.schedule import MeansDecay, tail_factor
from cam2sim.splat.state import TrainState
from cam2sim.splat.stop import diverged, plateau_reached
from cam2sim.splat.train_options import (
    TrainOptions,
    TrainResult,
    resolve_options,
)
from cam2sim.splat.views import downsample_views, load_views, loss_constants, sky_colour

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt
    import torch

    from cam2sim.splat.raster import RasterOutput
    from cam2sim.splat.scene import ChunkRecord, SceneRecord

__all__ = ["STREET_SCALE_M", "ChunkTrainer"]

_log = logging.getLogger(__name__)

STREET_SCALE_M = 10.0
"""Scene scale of metric street scenes, metres (see ``TrainOptions.scene_scale``): Gaussians
above 10 cm split rather than clone, above 1 m are pruned after the first opacity reset, and
centres start moving 1.6 mm a step. On a chunk of the 400 m route it raised held-out SSIM from
0.891 to 0.914 and cut LPIPS from 0.219 to 0.175 at 8,000 steps against the cameras' spread
(about 59 m); another chunk gained less (``docs/benchmarks.md``)."""

ANCHOR_EVERY = 10
"""Steps between two removals of the pose corrections' shared rigid motion
(:func:`~cam2sim.splat.pose_refine.remove_common_motion`): at the pose rates used (1e-5 a step)
ten steps move a camera by well under a millimetre."""


# --------------------------------------------------------------------------------- trainer


def _check_backend(options: TrainOptions, backend: str) -> None:
    """Refuse densification settings that need gsplat on another rasterizer."""
    dens = options.densify
    if dens.enabled and dens.absgrad and backend != "gsplat":
        msg = (
            "DensifyOptions.absgrad needs the gsplat rasterizer (CUDA); on this machine "
            f"the {backend} rasterizer runs: turn absgrad off"
        )
        raise StageError(msg)
    if dens.enabled and dens.strategy == "mcmc" and backend != "gsplat":
        msg = (
            f"densify.strategy='mcmc' needs the gsplat backend (CUDA), not {backend!r}; "
            "train on a CUDA device or use densify.strategy='auto'"
        )
        raise StageError(msg)


class ChunkTrainer:
    """Training state of one chunk; :meth:`step` runs one optimisation step."""

    def __init__(
        self,
        chunk: ChunkRecord,
        scene: SceneRecord,
        prep_dir: Path,
        points: tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]],
        options: TrainOptions,
        device: str,
        backend: Literal["gsplat", "torch"],
        time_share_s: float | None = None,
    ) -> None:
        import torch  # noqa: PLC0415

        options = resolve_options(options, backend)
        assert options.sky_weight is not None  # resolve_options decides both
        assert options.init_opacity is not None
        self.sky_weight, self.init_opacity = options.sky_weight, options.init_opacity
        self.mcmc = options.densify.enabled and options.densify.strategy == "mcmc"
        self.chunk = chunk
        self.options = options
        self.device = device
        self.backend = backend
        _check_backend(options, backend)
        self.absgrad = options.densify.enabled and options.densify.absgrad
        by_index = {f.index: f for f in scene.frames}
        missing = [i for i in chunk.frames if i not in by_index]
        if missing:
            msg = f"chunk {chunk.id} lists frames {missing[:5]} that scene.json does not have"
            raise StageError(msg)
        frames = sorted(
            (by_index[i] for i in chunk.frames if not by_index[i].held_out),
            key=lambda f: (f.progress_m, f.index),
        )
        if not frames:
            msg = f"chunk {chunk.id} has no training views (all held out?); re-run preparation"
            raise StageError(msg)
        from cam2sim.splat.densify import Densifier  # noqa: PLC0415 -- lazy: imports torch

        started = time.perf_counter()
        self.views = load_views(prep_dir, frames, options.downscale, device)
        self.setup_s = {"views": time.perf_counter() - started}
        # Level k: the views at 1/2**k size with their loss constants (level 0 = full size).
        self.levels = [(self.views, loss_constants(self.views))]
        for k in range(1, options.coarse_levels + 1):
            coarse = downsample_views(self.views, 2**k)
            self.levels.append((coarse, loss_constants(coarse)))
        self.timer = PhaseTimer(enabled=profiling_requested(options.profile), device=device)
        self.generator = torch.Generator(device=device).manual_seed(options.seed + chunk.id)
        self.cpu_generator = torch.Generator().manual_seed(options.seed + chunk.id)
        n_views = len(frames)
        n_val = min(options.n_val_views, n_views)
        spread = (n_views - 1) / max(1, n_val - 1)
        self.val_views = sorted({round(i * spread) for i in range(n_val)})
        self._order: list[int] = []
        self.scale_ambiguous = scene.scale_ambiguous
        started = time.perf_counter()
        self._build_models(points)
        self.setup_s["seeding"] = time.perf_counter() - started
        self._build_optimizers()
        self.densifier = (
            Densifier(
                options.densify,
                self.scene_scale,
                use_gsplat=options.densify.strategy == "gsplat",
                max_steps=options.max_steps,
            )
            if options.densify.enabled
            else None
        )
        self.background = torch.tensor(
            [[*options.background, 0.0]], dtype=torch.float32, device=device
        )
        # Robust weighting: the summed share of used pixels left out, and the steps it ran.
        self.outlier_sum = torch.zeros((), device=device)
        self.outlier_steps = 0
        self.state = TrainState(cap=options.max_steps, time_share=time_share_s)
        _log.info(
            "chunk %d: views loaded in %.1f s, Gaussians seeded in %.1f s",
            chunk.id, self.setup_s["views"], self.setup_s["seeding"],
        )  # fmt: skip

    # -- set-up ------------------------------------------------------------------------------
    def _build_models(self, points: tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]) -> None:
        from cam2sim.splat.model import SeedOptions, seed_models  # noqa: PLC0415 -- lazy: torch

        opts = self.options
        self.n_ground = self.n_cleared = 0
        height = None
        if opts.ground_points or opts.clear_path > 0:
            height = self._camera_height(points[0])
        self.path, self.clear_radius = self._clearance(height)
        if opts.ground_points:
            points = self._with_ground(points, height)
        seeded = seed_models(
            *points,
            self.views.frames,
            sky_rgb=sky_colour(self.views),
            options=SeedOptions(
                sh_degree=opts.sh_degree,
                opacity=self.init_opacity,
                sky_points=opts.sky_points,
                sky_radius_m=opts.sky_radius_m,
                max_points=opts.max_init_points,
                seed=opts.seed + self.chunk.id,
            ),
            device=self.device,
        )
        if seeded is None:
            msg = (
                f"chunk {self.chunk.id}: none of the {len(points[0])} points of points.npz is "
                "seen by its training views; check the poses or re-run splat preparation"
            )
            raise StageError(msg)
        self.street, self.sky = seeded.street, seeded.sky
        self.n_initial = len(self.street)
        if opts.scene_scale is not None:
            self.scene_scale = opts.scene_scale
        elif self.scale_ambiguous:
            self.scene_scale = seeded.scene_scale
        else:
            self.scene_scale = STREET_SCALE_M
        self.sky_radius = seeded.sky_radius_m
        _log.info(
            "chunk %d: %d training views (%dx%d), %d street Gaussians from points, %d sky "
            "Gaussians at %.1f m, scene scale %.2f m",
            self.chunk.id,
            len(self.views.frames),
            self.views.width,
            self.views.height,
            len(self.street),
            opts.sky_points,
            self.sky_radius,
            self.scene_scale,
        )
        cap = opts.densify.mcmc_cap
        if self.mcmc and len(self.street) >= cap:
            _log.warning(
                "chunk %d: MCMC starts with %d street Gaussians, at or above its cap "
                "densify.mcmc_cap=%d, so it relocates faded ones but never grows; raise "
                "mcmc_cap, or start from fewer with ground_points or max_init_points (%d of "
                "them are ground seeds)",
                self.chunk.id,
                len(self.street),
                cap,
                self.n_ground,
            )

    def _build_optimizers(self) -> None:
        import torch  # noqa: PLC0415

        lr = self.options.lr
        rates = {
            "means": lr.means * self.scene_scale,
            "scales": lr.scales,
            "quats": lr.quats,
            "opacities": lr.opacities,
            "sh0": lr.sh0,
            "shN": lr.sh_rest,
        }
        self.optimizers: dict[str, torch.optim.Optimizer] = {
            name: torch.optim.Adam([p], lr=rates[name], eps=1e-15, fused=True)
            for name, p in self.street.params.items()
        }
        # The sky's parameters share one optimizer (a group each): fewer optimizer calls per step.
        sky_groups = [
            {"params": [p], "lr": rates[name]}
            for name, p in self.sky.params.items()
            if p.requires_grad and p.numel() > 0
        ]
        eye = torch.eye(3, 4, device=self.device)
        self.appearance = torch.nn.Parameter(eye.repeat(len(self.views.frames), 1, 1))
        self.appearance.requires_grad = self.options.appearance
        self.extra_optimizers: list[torch.optim.Optimizer] = []
        if sky_groups:
            self.extra_optimizers.append(torch.optim.Adam(sky_groups, eps=1e-15, fused=True))
        if self.options.appearance:
            self.extra_optimizers.append(
                torch.optim.Adam([self.appearance], lr=lr.appearance, fused=True)
            )
        self.pose_delta: torch.nn.Parameter | None = None
        if lr.poses > 0:
            zeros = torch.zeros(len(self.views.frames), 6, device=self.device)
            self.pose_delta = torch.nn.Parameter(zeros)
            self.extra_optimizers.append(
                torch.optim.Adam([self.pose_delta], lr=lr.poses, weight_decay=1e-6, fused=True)
            )
        self.means = MeansDecay.over(rates["means"], self.options.max_steps)
        self.non_finite_steps = torch.zeros((), dtype=torch.int64, device=self.device)
        # The scene's other rates decay after densification (LearningRates.tail).
        dens = self.options.densify
        self.tail_start = dens.refine_stop_at if dens.enabled else 0
        self.tail_groups: list[tuple[dict[str, Any], float]] = []
        if lr.tail is not None and lr.tail < 1.0:
            scene_optimizers = [o for n, o in self.optimizers.items() if n != "means"]
            if lr.tail_views:  # the sky's, the per-view transforms' and pose corrections'
                scene_optimizers += self.extra_optimizers
            elif sky_groups:
                scene_optimizers.append(self.extra_optimizers[0])
            self.tail_groups = [
                (group, float(group["lr"])) for o in scene_optimizers for group in o.param_groups
            ]

    # -- steps -------------------------------------------------------------------------------
    def _level(self) -> int:
        """The resolution level of this step (0 = full size, see ``coarse_levels``)."""
        return max(0, self.options.coarse_levels - self.step_no // self.options.coarse_every)

    def _render(
        self, view: int, degree: int, *, absgrad: bool = False, level: int = 0
    ) -> tuple[RasterOutput, torch.Tensor, torch.Tensor]:
        """Render training view ``view``: (raster output, [H, W, 3] rgb, [H, W] sky share)."""
        from cam2sim.splat.model import gather_splats  # noqa: PLC0415 -- lazy: imports torch

        v = self.levels[level][0]
        inputs = gather_splats(
            self.street, self.sky, v.campos[view : view + 1], degree, backend=self.backend
        )
        viewmats = v.viewmats[view : view + 1]
        if self.pose_delta is not None:
            viewmats = se3_exp(self.pose_delta[view : view + 1]) @ viewmats
        out = rasterize(
            inputs.means,
            inputs.quats,
            inputs.scales,
            inputs.opacities,
            inputs.colors,
            viewmats,
            v.Ks[view : view + 1],
            v.width,
            v.height,
            backgrounds=self.background,
            backend=self.backend,
            absgrad=absgrad,
            tile_size=self.options.tile_size,
            antialiased=self.options.antialiased,
        )
        image = out.colors[0]
        rgb = image[..., :3]
        if self.options.appearance:
            rgb = apply_affine(rgb, self.appearance[view])
        return out, rgb, image[..., 3]

    def _loss(
        self, view: int, rgb: torch.Tensor, sky_share: torch.Tensor, level: int
    ) -> torch.Tensor:
        (v, c), opts = self.levels[level], self.options
        sky = None
        if (
            c.sky_pixels is not None
            and c.street_pixels is not None
            and c.sky_scale is not None
            and c.street_scale is not None
            and self.sky_weight > 0
            and opts.sky_points > 0
        ):
            sky = (
                sky_share,
                c.sky_pixels[view] * c.sky_scale[view],
                c.street_pixels[view] * c.street_scale[view],
            )
        target = v.images[view].float() / 255.0
        mask, l1_scale = v.masks[view], c.l1_scale[view]
        if opts.robust.active(self.step_no):
            used = mask
            mask = robust_keep(rgb, target, used, opts.robust)
            kept = mask.sum()
            l1_scale = 1.0 / (3.0 * kept.clamp(min=1))
            self.outlier_sum += 1.0 - kept / used.sum().clamp(min=1)
            self.outlier_steps += 1
        loss = photometric_loss(rgb, target, mask, l1_scale, opts.ssim_weight, sky, self.sky_weight)
        if self.mcmc:
            dens, params = opts.densify, self.street.params
            loss = loss + mcmc_regulariser(
                params["opacities"], params["scales"], dens.mcmc_opacity_reg, dens.mcmc_scale_reg
            )
        return loss

    def _next_view(self) -> int:
        import torch  # noqa: PLC0415

        if not self._order:
            n = len(self.views.frames)
            self._order = torch.randperm(n, generator=self.cpu_generator).tolist()
        return self._order.pop()

    def step(self) -> None:
        """Run one optimisation step (and a validation when one is due)."""
        import torch  # noqa: PLC0415

        start = time.perf_counter()
        timer = self.timer
        timer.begin()
        opts = self.options
        view = self._next_view()
        degree = min(opts.sh_degree, self.step_no // opts.sh_degree_interval)
        level = self._level()
        out, rgb, sky_share = self._render(view, degree, absgrad=self.absgrad, level=level)
        if self.densifier is not None and out.means2d.requires_grad:
            out.means2d.retain_grad()
        timer.mark("render")
        loss = self._loss(view, rgb, sky_share, level)
        timer.mark("loss")
        torch.autograd.backward(loss)
        timer.mark("backward")
        adam_step(
            (*self.optimizers.values(), *self.extra_optimizers),
            finite=True,
            non_finite_steps=self.non_finite_steps,
        )
        if self.pose_delta is not None and self.step_no % ANCHOR_EVERY == 0:
            remove_common_motion(self.pose_delta, self.levels[0][0].viewmats)
        timer.mark("optimizer")
        if self.path is not None and self.step_no % opts.densify.refine_every == 0:
            from cam2sim.splat.clearance import clear_path  # noqa: PLC0415

            self.n_cleared += clear_path(self.street, self.optimizers, self.path, self.clear_radius)
        if self.densifier is not None:
            self.densifier.post_backward(
                self.step_no,
                self.street,
                self.optimizers,
                out,
                len(self.street),
                self.generator,
                means_lr=self.means.lr,
            )
            timer.mark("densify")
        self.state.step += 1
        means_lr = self.means.advance()
        for group in self.optimizers["means"].param_groups:
            group["lr"] = means_lr
        factor = None
        if self.tail_groups:
            factor = tail_factor(self.step_no, self.tail_start, self.state.cap, opts.lr.tail or 1.0)
        if factor is not None:
            for group, base in self.tail_groups:
                group["lr"] = base * factor
        spent = self.state.seconds + time.perf_counter() - start
        if (
            self.step_no % opts.val_every == 0
            or self.step_no >= self.state.cap
            or self.state.out_of_time(spent)
        ):
            val_start = time.perf_counter()
            self._validate(spent)
            self.state.val_seconds = time.perf_counter() - val_start
            timer.mark("validate")
        timer.end()
        self.state.seconds += time.perf_counter() - start

    def _validate(self, spent: float) -> None:
        import torch  # noqa: PLC0415

        opts = self.options
        degree = min(opts.sh_degree, self.step_no // opts.sh_degree_interval)
        with torch.no_grad():
            psnrs, ssims = [], []
            for view in self.val_views:
                _, rgb, _ = self._render(view, degree)
                target = self.views.images[view].float() / 255.0
                mask = self.views.masks[view]
                psnrs.append(masked_psnr(rgb, target, mask))
                # SSIM as in the loss: excluded pixels copied from the target.
                shown = torch.where(mask[..., None], rgb.clamp(0.0, 1.0), target)
                ssims.append(ssim(shown, target))
            ssim_mean = float(torch.stack(ssims).mean())
        psnr = float(np.mean(psnrs))
        self.state.history.append((self.step_no, psnr, ssim_mean))
        _log.info(
            "chunk %d step %d: held-in PSNR %.2f dB, SSIM %.4f, %d Gaussians",
            self.chunk.id,
            self.step_no,
            psnr,
            ssim_mean,
            len(self.street),
        )
        skipped = int(self.non_finite_steps)
        if diverged(skipped, self.step_no, psnr):
            msg = (
                f"splat chunk {self.chunk.id} diverged at step {self.step_no}: NaN or inf "
                f"gradients on {skipped} steps, held-in PSNR {psnr:.2f} dB; nothing was written "
                "for it. Look for broken frames in the chunk's images and masks, or lower the "
                "learning rates (TrainOptions.lr), then train again"
            )
            raise StageError(msg)
        state = self.state
        if state.step >= opts.min_steps and self._plateaued():
            state.stop("plateau")
        elif state.step >= opts.max_steps:
            state.stop("max_steps")
        elif state.time_share is not None:
            if state.step >= state.cap or state.out_of_time(spent):
                state.stop("time")
            else:
                self._fit_to_time(spent)

    @property
    def step_no(self) -> int:
        """Steps done (:attr:`TrainState.step`)."""
        return self.state.step

    @property
    def done(self) -> bool:
        """Whether training has stopped (:attr:`TrainState.done`)."""
        return self.state.done

    def _fit_to_time(self, spent: float) -> None:
        """Move the step cap to where the time share runs out, with the schedules that end there."""
        cap = self.state.fit_cap(spent, self.options.max_steps)
        if cap is not None:
            # The means' learning rate reaches its final value at the new cap, and no opacity
            # reset falls within reset_every steps of it.
            self.means.aim(self.state.step, cap)
            if self.densifier is not None:
                self.densifier.end_at(cap)

    def _plateaued(self) -> bool:
        opts = self.options
        return plateau_reached(
            self.state.history, opts.patience, opts.min_gain_db, opts.min_gain_ssim
        )

    # -- output ------------------------------------------------------------------------------
    def save(self, models_dir: Path) -> TrainResult:
        """Write the chunk model and return the result."""
        from cam2sim.splat.model import (  # noqa: PLC0415 -- lazy: imports torch
            ChunkHeader,
            ChunkModel,
            ViewRecord,
            chunk_model_path,
            export_ply,
            outliers_path,
            save_chunk_model,
        )

        poses = np.stack([f.T() for f in self.views.frames])
        correction = None
        deltas: list[list[float] | None] = [None] * len(poses)
        if self.pose_delta is not None:
            delta = self.pose_delta.detach().cpu().double().numpy()
            poses = corrected_pose(poses, delta)
            correction = correction_sizes(delta)
            deltas = delta.tolist()
        views = [
            ViewRecord(
                index=f.index,
                progress_m=f.progress_m,
                position=pose[:3, 3].tolist(),
                forward=pose[:3, 2].tolist(),
                down=pose[:3, 1].tolist(),
                correction=delta,
                from_recorded=f.from_recorded,
            )
            for f, pose, delta in zip(self.views.frames, poses, deltas, strict=True)
        ]
        header = ChunkHeader(
            chunk_id=self.chunk.id,
            start_m=self.chunk.start_m,
            end_m=self.chunk.end_m,
            sh_degree=self.street.sh_degree,
            n_gaussians=len(self.street),
            n_sky=self.options.sky_points,
            scene_scale=self.scene_scale,
            sky_radius_m=self.sky_radius,
            background=list(self.options.background),
            train_views=views,
            steps=self.step_no,
            best_val_psnr_db=self.state.best,
            val_history=list(self.state.history),
            backend=self.backend,
            stopped=self.state.stopped,
            notes=self._notes(),
            antialiased=self.options.antialiased,
        )
        model = ChunkModel(
            header=header, gaussians=self.street, sky=self.sky, appearance=self.appearance.detach()
        )
        path = chunk_model_path(models_dir, self.chunk.id)
        save_chunk_model(model, path)
        if self.options.write_ply:
            export_ply(self.street, path.with_suffix(".ply"), extra=self.sky)
        if self.options.robust.quantile > 0:
            self._write_outliers(outliers_path(path))
        _log.info(
            "chunk %d: %s after %d steps, best held-in PSNR %s, %d Gaussians -> %s",
            self.chunk.id,
            self.state.stopped,
            self.step_no,
            "n/a" if self.state.best is None else f"{self.state.best:.2f} dB",
            len(self.street),
            path,
        )
        return TrainResult(
            chunk_id=self.chunk.id,
            model_path=path,
            steps=self.step_no,
            stopped=self.state.stopped,
            n_gaussians=len(self.street),
            n_initial_gaussians=self.n_initial,
            n_sky=self.options.sky_points,
            n_train_views=len(self.views.frames),
            best_val_psnr_db=self.state.best,
            val_history=tuple(self.state.history),
            train_seconds=self.state.seconds,
            backend=self.backend,
            device=self.device,
            phase_ms=self.timer.summary(),
            robust_outlier_share=(
                float(self.outlier_sum) / self.outlier_steps if self.outlier_steps else None
            ),
            pose_correction=correction,
            densify_strategy=self.options.densify.strategy
            if self.options.densify.enabled
            else "off",
            non_finite_steps=int(self.non_finite_steps),
        )

    def _write_outliers(self, path: Path, n_views: int = 4) -> None:
        """Picture of the training views whose pixels the robust weighting leaves out most.

        Each view is rendered once more with the final model and judged as in the last steps.
        """
        import cv2  # noqa: PLC0415
        import torch  # noqa: PLC0415

        from cam2sim.core.files import write_bytes_atomic  # noqa: PLC0415
        from cam2sim.splat.robust import outlier_montage  # noqa: PLC0415

        v, opts = self.views, self.options
        shares, masks = [], []
        degree = min(opts.sh_degree, self.step_no // opts.sh_degree_interval)
        with torch.no_grad():
            for view in range(len(v.frames)):
                _, rgb, _ = self._render(view, degree)
                target = v.images[view].float() / 255.0
                used = v.masks[view]
                out = used & ~robust_keep(rgb, target, used, opts.robust)
                shares.append(float(out.sum()) / max(1, int(used.sum())))
                masks.append(out.cpu().numpy())
        order = sorted(range(len(shares)), key=lambda i: -shares[i])[:n_views]
        picture = outlier_montage(
            [v.images[i].cpu().numpy() for i in order],
            [masks[i] for i in order],
            [f"frame {v.frames[i].index}: {shares[i]:.0%} left out" for i in order],
        )
        ok, data = cv2.imencode(".jpg", picture[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 88])
        if ok:
            write_bytes_atomic(path, data.tobytes())

    def _usable(self) -> npt.NDArray[np.bool_]:
        """``(M, H, W)`` pixels of the training views that show the street (not hood, not sky)."""
        v = self.views
        usable = v.masks if v.sky is None else v.masks & ~v.sky
        return np.asarray(usable.cpu().numpy(), dtype=np.bool_)

    def _camera_height(self, xyz: npt.NDArray[np.float32]) -> float | None:
        """The cameras' height over the road ahead (:func:`cam2sim.splat.ground.camera_height`)."""
        from cam2sim.splat.ground import camera_height  # noqa: PLC0415

        v = self.views
        return camera_height(
            xyz, np.stack([f.T() for f in v.frames]), v.Ks.double().cpu().numpy(), self._usable()
        )

    def _clearance(self, height: float | None) -> tuple[torch.Tensor | None, float]:
        """The training cameras' path (in path order) and the radius cleared around it."""
        import torch  # noqa: PLC0415

        if self.options.clear_path <= 0:
            return None, 0.0
        if height is None:
            _log.warning(
                "chunk %d: too few points on the road under the cameras to know their height; "
                "the drive's path is not cleared",
                self.chunk.id,
            )
            return None, 0.0
        centres = np.stack([f.T()[:3, 3] for f in self.views.frames]).astype(np.float32)
        path = torch.from_numpy(centres).to(self.device)
        return path, self.options.clear_path * height

    def _with_ground(
        self, points: tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]], height: float | None
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
        """``points`` and the ground seeds under the training views (:mod:`.ground`)."""
        from cam2sim.splat.ground import ground_points  # noqa: PLC0415

        v = self.views
        xyz, rgb = ground_points(
            points[0],
            np.stack([f.T() for f in v.frames]),
            v.Ks.double().cpu().numpy(),
            v.images.cpu().numpy(),
            self._usable(),
            count=self.options.ground_points or 0,
            seed=self.options.seed + self.chunk.id,
            height=height,
        )
        self.n_ground = len(xyz)
        return np.concatenate([points[0], xyz]), np.concatenate([points[1], rgb])

    def _notes(self) -> list[str]:
        """The header's notes: how the model grew, and any Gaussians that broke on the way."""
        notes = [self._densify_note()]
        if self.n_ground:
            notes.append(f"{self.n_ground} ground seeds")
        if self.path is not None:
            notes.append(
                f"{self.n_cleared} Gaussians cleared from the drive's path "
                f"(radius {self.clear_radius:.3g} scene units)"
            )
        broken = self.densifier.n_non_finite if self.densifier is not None else 0
        if broken:
            notes.append(f"{broken} Gaussians with NaN or inf parameters made transparent")
        skipped = int(self.non_finite_steps)
        if skipped:
            notes.append(f"NaN or inf gradient values on {skipped} steps, kept out of the model")
        return notes

    def _densify_note(self) -> str:
        """How the model grew, for the header's notes."""
        opts = self.options
        if not opts.densify.enabled:
            return "densification off"
        note = (
            f"densification {opts.densify.strategy} until step {opts.densify.refine_stop_at}, "
            f"initial opacity {self.init_opacity:g}, sky-share weight {self.sky_weight:g}"
        )
        if self.tail_groups:
            note += f", learning rates to {opts.lr.tail:g}x after densification"
            if opts.lr.tail_views and opts.appearance:
                note += " (the per-view colour transforms' too)"
        if opts.densify.strategy == "mcmc" and opts.densify.mcmc_error_weight > 0:
            note += f", draw weighted by the image error ({opts.densify.mcmc_error_weight:g})"
        if opts.densify.strategy == "mcmc" and opts.densify.mcmc_inherit_moments:
            note += ", copies keep their originals' Adam moments"
        return note


# ---------------------------------------------------------------------------- entry points
