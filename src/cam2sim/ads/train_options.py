"""How a DAVE-2 network is trained: :class:`TrainOptions` and its presets.

The options are a plain record, importable without torch (the CLI and the pipeline build them
before anything trains); :mod:`cam2sim.ads.train` does the training.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal

from cam2sim.ads.dave2 import Dave2Config

__all__ = ["TrainOptions"]


@dataclass(frozen=True)
class TrainOptions:
    """How ``cam2sim ads train`` trains.

    Attributes:
        signal: Steering signal name (``signals/<name>.csv``): the model's own recorded
            commands or the measured steering.
        epochs: Most training epochs.
        batch_size: Frames per step.
        learning_rate: Adam step size.
        weight_decay: Adam L2 penalty.
        val_fraction: Share of the drive held out for validation.
        split: ``blocks``: every ``round(1 / val_fraction)``-th block of ``block_s`` seconds
            validates, so validation sees the whole drive's kinds of road (one drive of a
            street has one of each bend: its last 20 % may hold a bend nothing before it
            shows); ``tail``: the drive's end validates.
        block_s: Length of the validation blocks, seconds.
        gap_s: Training frames this close (seconds) to a validation frame are dropped.
        patience: Stop after this many epochs without a better validation loss.
        keep: ``best``: the epoch of the lowest validation loss (early stopping with
            ``patience``); ``last``: train every epoch and keep the last one, for a drive too
            short for its held-out tail to stand for it (the demo's: a straight, which says
            nothing about a bend).
        refit_all: After the run that is validated (and reported), train a fresh network on
            every frame, validation frames included, for as many epochs as the kept one had,
            and keep that one. For a closed-loop test on the recorded street itself, where a
            held-out stretch is a stretch the policy never saw (one drive has one of each
            bend); the report's validation figures then describe the method, not the kept
            network.
        validate: With ``refit_all``: False skips the validated run and trains only the
            network that is kept, on every frame for ``epochs`` epochs. The same network
            (the same seed, frames and epochs: bit for bit on one machine) in about half the
            time, without validation figures: for runs that read only the closed loop (the
            street benchmark).
        augment: Augment training batches (brightness, shadow, shift; flip if ``flip``).
        shift_px: Largest horizontal shift, network-input pixels.
        shift_steering_per_px: Steering correction per pixel of shift (content moved right by
            ``d`` px -> label ``- d * this``: steer towards where the road went; positive
            steering is left). None: ``0.004 *`` the 95th percentile of ``|steering|``.
        flip: Also mirror half the batches' images and negate their steering (only for
            left/right-symmetric traffic scenes).
        blur_px: Largest Gaussian blur (sigma, network-input pixels) of half of each batch,
            and a contrast cut of up to 40 % on the same half: a simulated camera (a splat
            short of detail, a raster's flat shading) is softer and flatter than the recorded
            frames, and a network that never saw a soft frame reads softness as a turn. 0: off.
        recovery_m: Largest sideways displacement of the recovery views
            (:mod:`cam2sim.ads.recovery`), metres; 0 turns them off. They replace the shift
            when the camera geometry is known (``train_dave2(geometry=...)``).
        recovery_deg: Largest turn of the recovery views, degrees.
        recovery_lookahead_m: Pure-pursuit look-ahead of their labels, metres.
        recovery_share: Share of each batch shown displaced.
        config: Network sizes and preprocessing; None: the published ones, fitted to the
            workspace's camera by the ads stage (:meth:`Dave2Config.for_camera`).
        balance: How much rarer steering values are drawn more often (0: every frame once an
            epoch, in random order; 1: each of :data:`cam2sim.ads.train.BALANCE_BINS` bins of
            the steering range as often as any other, frames drawn with replacement; between:
            weights ``count(bin) ** -balance``). One drive has one sharp turn among long
            straights; unbalanced, the loss barely sees it.
        seed: Seeds torch and numpy.
        device: ``cuda``/``cpu``; None takes CUDA when available.
        workers: Threads decoding frames.
    """

    signal: str = "steering"
    epochs: int = 30
    batch_size: int = 64
    learning_rate: float = 1e-3
    weight_decay: float = 1e-5
    val_fraction: float = 0.2
    split: Literal["blocks", "tail"] = "tail"
    block_s: float = 4.0
    gap_s: float = 1.0
    patience: int = 5
    keep: Literal["best", "last"] = "best"
    refit_all: bool = False
    validate: bool = True
    augment: bool = True
    shift_px: int = 10
    shift_steering_per_px: float | None = None
    flip: bool = False
    blur_px: float = 0.0
    recovery_m: float = 0.6
    recovery_deg: float = 4.0
    recovery_lookahead_m: float = 10.0
    recovery_share: float = 0.5
    balance: float = 0.0
    config: Dave2Config | None = None
    seed: int = 0
    device: str | None = None
    workers: int = 2

    @classmethod
    def same_street(cls, signal: str = "steering", **changes: Any) -> TrainOptions:
        """The preset of ``cam2sim run``: a closed-loop test on the recorded street itself.

        60 epochs, the last kept, validated on blocks spread over the drive and then refitted
        on every frame (:attr:`refit_all`): the policy is tested where it was trained, as the
        paper's DAVE-2, so no stretch of the street is left unseen. On KITTI 03 (one 80 s
        drive, steering derived from its poses) early stopping on its last 20 % kept epoch 6
        of 11, whose views 0.5 m beside the path moved its steering by 0.02 units where the
        recovery labels say 0.46; this preset moves it by 0.17 and in the right direction
        for 99 % of the frames. Soft frames (:attr:`blur_px` 3) cut its bias on a 19.6 dB CPU
        splat's straights from -0.61 to -0.35 units and on the raster camera's from -3.0 to
        -1.0 (docs/benchmarks.md).
        """
        preset = cls(
            signal=signal, epochs=60, keep="last", split="blocks", refit_all=True, blur_px=3.0
        )
        return replace(preset, **changes)

    @property
    def dave2(self) -> Dave2Config:
        """The network's sizes: :attr:`config`, or the published ones when it is None."""
        return self.config or Dave2Config()

    @property
    def uses_recovery(self) -> bool:
        """Whether batches get recovery views (when the camera geometry is known)."""
        return self.augment and self.recovery_m > 0

    def __post_init__(self) -> None:
        bad = {
            k: v
            for k, v in (
                ("epochs", self.epochs),
                ("batch_size", self.batch_size),
                ("patience", self.patience),
                ("workers", self.workers),
            )
            if v < 1
        }
        if bad:
            msg = f"training options must be >= 1, got {bad}"
            raise ValueError(msg)
        if (
            not 0.0 < self.val_fraction < 1.0
            or self.gap_s < 0
            or self.shift_px < 0
            or not self.block_s > 0
            or self.blur_px < 0
        ):
            msg = (
                "val_fraction must lie in (0, 1), gap_s, shift_px and blur_px must be >= 0, "
                f"block_s > 0; got {self.val_fraction}, {self.gap_s}, {self.shift_px}, "
                f"{self.blur_px}, {self.block_s}"
            )
            raise ValueError(msg)
        if not self.validate and not (self.refit_all and self.keep == "last"):
            msg = (
                "validate=False trains only the network refit_all keeps: it needs "
                "refit_all=True and keep='last' (nothing validated chooses an epoch)"
            )
            raise ValueError(msg)
        if not 0.0 <= self.balance <= 1.0:
            msg = f"balance must lie in [0, 1] (0 off, 1 every bin alike), not {self.balance}"
            raise ValueError(msg)
        if (
            self.recovery_m < 0
            or self.recovery_deg < 0
            or not self.recovery_lookahead_m > 0
            or not 0.0 <= self.recovery_share <= 1.0
        ):
            msg = (
                "recovery_m and recovery_deg must be >= 0, recovery_lookahead_m > 0 and "
                f"recovery_share in [0, 1]; got {self.recovery_m}, {self.recovery_deg}, "
                f"{self.recovery_lookahead_m}, {self.recovery_share}"
            )
            raise ValueError(msg)
        if not self.learning_rate > 0:
            msg = f"learning_rate must be positive, got {self.learning_rate}"
            raise ValueError(msg)
