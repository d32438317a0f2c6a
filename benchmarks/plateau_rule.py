"""How often the plateau rule stops a splat chunk on noise (issue 37): held-in curves from logs.

Reads the held-in validations (``chunk N step S: held-in PSNR P dB, SSIM Q``) of the chunk
logs given (a benchmark's ``logs/*.log``), fits each chunk's curve from step 1,000 on as
``a + b ln(step)`` (PSNR and SSIM apart), and reports per chunk where it stopped, its fitted
gains and the step where each fitted trend falls below the preset's minimum gain (the plateau
the rule means to find), then the scatter of the validations about the fits. It then draws
curves of the median fitted shape with that scatter and counts where
:func:`cam2sim.splat.stop.plateau_reached` stops them, for each ``--patience``, with the demo's
CUDA preset otherwise (validations every 250 steps, 2,500-5,000 steps, 0.5 dB and 0.005 SSIM
per 1,000 steps).

Run from the repository root::

    PYTHONPATH=src python benchmarks/plateau_rule.py docs/results/issue37-gpu-preset/logs/*.log
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from cam2sim.splat.stop import plateau_reached

LINE = re.compile(r"chunk (\d+) step (\d+): held-in PSNR ([\d.]+) dB, SSIM ([\d.]+)")


def curves(paths: list[Path]) -> dict[str, np.ndarray]:
    """``{"LOG chunk N": (validations, 3) of step, PSNR, SSIM}`` from the logs."""
    out: dict[str, list[tuple[float, float, float]]] = {}
    for path in paths:
        for m in LINE.finditer(path.read_text()):
            chunk, step, psnr, ssim = m.groups()
            out.setdefault(f"{path.stem} chunk {chunk}", []).append(
                (float(step), float(psnr), float(ssim))
            )
    return {k: np.array(v) for k, v in out.items()}


def log_fit(steps: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)`` of ``a + b ln(step)`` and the residuals."""
    design = np.c_[np.ones(len(steps)), np.log(steps)]
    coef = np.linalg.lstsq(design, values, rcond=None)[0]
    return coef, values - design @ coef


def simulate(
    rng: np.random.Generator,
    shape: tuple[float, float],
    noise: tuple[float, float],
    patience: int,
    args: argparse.Namespace,
    draws: int,
) -> np.ndarray:
    """Stop steps of ``draws`` noisy curves of slopes ``shape`` (PSNR, SSIM per ln step)."""
    steps = np.arange(args.val_every, args.max_steps + 1, args.val_every, dtype=np.float64)
    psnr = shape[0] * np.log(steps) + rng.normal(0.0, noise[0], (draws, len(steps)))
    ssim = shape[1] * np.log(steps) + rng.normal(0.0, noise[1], (draws, len(steps)))
    stops = np.full(draws, args.max_steps, dtype=np.float64)
    for d in range(draws):
        history = list(zip(steps.tolist(), psnr[d].tolist(), ssim[d].tolist(), strict=True))
        for i, step in enumerate(steps):
            if step >= args.min_steps and plateau_reached(
                history[: i + 1], patience, args.min_gain_db, args.min_gain_ssim
            ):
                stops[d] = step
                break
    return stops


def main() -> None:
    """Report the chunks of the logs given and the simulated stops."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--patience", default="3,5,7,9")
    parser.add_argument("--val-every", type=int, default=250)
    parser.add_argument("--min-steps", type=int, default=2_500)
    parser.add_argument("--max-steps", type=int, default=5_000)
    parser.add_argument("--min-gain-db", type=float, default=0.5)
    parser.add_argument("--min-gain-ssim", type=float, default=0.005)
    parser.add_argument("--draws", type=int, default=2_000)
    args = parser.parse_args()
    gains, residuals = [], []
    print(
        "| chunk | stopped at | PSNR gain (dB / ln step) | SSIM gain | PSNR trend under the "
        "minimum from | SSIM from |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for name, c in sorted(curves(args.logs).items()):
        later = c[:, 0] >= 1_000
        if later.sum() < 4:
            continue
        (_, b), r_psnr = log_fit(c[later, 0], c[later, 1])
        (_, bs), r_ssim = log_fit(c[later, 0], c[later, 2])
        gains.append((b, bs))
        residuals.append((r_psnr, r_ssim))
        # d/dstep (b ln step) per 1,000 steps falls below the minimum at step 1000 b / minimum.
        print(
            f"| {name} | {int(c[-1, 0])} | {b:.2f} | {bs:.4f} | "
            f"{1_000 * b / args.min_gain_db:.0f} | {1_000 * bs / args.min_gain_ssim:.0f} |"
        )
    if not gains:
        msg = "no chunk with 4 validations from step 1,000 in the logs given"
        raise SystemExit(msg)
    median = np.median(np.array(gains), axis=0)
    shape = (float(median[0]), float(median[1]))
    noise = (
        float(np.concatenate([r[0] for r in residuals]).std()),
        float(np.concatenate([r[1] for r in residuals]).std()),
    )
    print(
        f"\n{len(gains)} chunks: median gains {shape[0]:.2f} dB and {shape[1]:.4f} SSIM per ln "
        f"step; scatter about the fits {noise[0]:.2f} dB, {noise[1]:.4f} SSIM\n"
    )
    rng = np.random.default_rng(0)
    print("| patience (window, steps) | mean stop | 10th pct | stopped by 3,000 | at the cap |")
    print("| --- | --- | --- | --- | --- |")
    for patience in (int(p) for p in args.patience.split(",")):
        stops = simulate(rng, shape, noise, patience, args, args.draws)
        print(
            f"| {patience} ({patience * args.val_every:,}) | {stops.mean():.0f} | "
            f"{np.percentile(stops, 10):.0f} | {np.mean(stops <= 3_000):.0%} | "
            f"{np.mean(stops >= args.max_steps):.0%} |"
        )


if __name__ == "__main__":
    main()
