"""``cam2sim ads``: train, export and serve the system under test (DAVE-2)."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer

from cam2sim.cli.display import StageErrorGroup, console, error_exit, progress_bars
from cam2sim.core.errors import Cam2SimError, ConfigError
from cam2sim.core.workspace import Workspace

if TYPE_CHECKING:
    from cam2sim.ads.train import RecoveryRecord

__all__ = ["ads_app"]

ads_app = typer.Typer(
    cls=StageErrorGroup,
    help="The system under test: train DAVE-2 on the recording, export it, serve it.",
    no_args_is_help=True,
    rich_markup_mode=None,  # click's plain help: readable at 80 columns
)


@ads_app.command("train")
def train(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    signal: Annotated[
        str, typer.Option(help="Steering signal to learn (a name under dataset/signals/).")
    ] = "steering",
    epochs: Annotated[
        int | None,
        typer.Option(min=1, help="Most training epochs (default: 30; 60 with --same-street)."),
    ] = None,
    same_street: Annotated[
        bool,
        typer.Option(
            "--same-street",
            help=(
                "Train as `cam2sim run` does, for a closed-loop test on the recorded street: "
                "validate on 4 s blocks spread over the drive, then train again on every frame; "
                "half of each batch softened (blur, less contrast) as simulated frames are."
            ),
        ),
    ] = False,
    validate: Annotated[
        bool,
        typer.Option(
            "--validate/--no-validate",
            help=(
                "With --same-street: --no-validate trains only the network that is kept, on "
                "every frame (the same network in half the time, without validation figures)."
            ),
        ),
    ] = True,
    batch_size: Annotated[int, typer.Option("--batch-size", min=1)] = 64,
    augment: Annotated[bool, typer.Option("--augment/--no-augment")] = True,
    recovery_m: Annotated[
        float,
        typer.Option(
            "--recovery-m",
            min=0.0,
            help=(
                "Largest sideways displacement of the recovery views (frames re-projected "
                "beside the recorded path, labelled to steer back), metres; 0 turns them off."
            ),
        ),
    ] = 0.6,
    recovery_deg: Annotated[
        float, typer.Option("--recovery-deg", min=0.0, help="Largest turn of the recovery views.")
    ] = 4.0,
    balance: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help=(
                "Draw rare steering values more often: 0 off, 1 every part of the steering "
                "range alike (a drive's one sharp turn among its straights)."
            ),
        ),
    ] = 0.0,
    seed: Annotated[int, typer.Option()] = 0,
    force: Annotated[bool, typer.Option(help="Train again even if up to date.")] = False,
) -> None:
    """Train DAVE-2 on the dataset's frames and a steering signal; writes WS/ads/.

    Example: cam2sim ads train ws --signal steering_cmd --epochs 40
    """
    import dataclasses  # noqa: PLC0415

    from cam2sim.ads.train_options import TrainOptions  # noqa: PLC0415 -- lazy: imports cv2
    from cam2sim.stages.ads import train_ads  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    if not validate and not same_street:
        msg = "--no-validate goes with --same-street (only its network is trained on every frame)"
        raise ConfigError(msg)
    base = TrainOptions.same_street(signal) if same_street else TrainOptions(signal=signal)
    opts = dataclasses.replace(
        base,
        epochs=base.epochs if epochs is None else epochs,
        batch_size=batch_size,
        augment=augment,
        recovery_m=recovery_m,
        recovery_deg=recovery_deg,
        balance=balance,
        seed=seed,
        validate=validate,
    )
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = train_ads(ws, options=opts, force=force, progress=sink)
    rep = result.report
    if rep is None:
        console.print(f"{result.model} is up to date (use --force to train again)")
        return
    if rep.val_rmse is None or rep.baseline_mse is None or rep.val_mae is None:
        console.print(
            f"{result.model}: trained on all {rep.train_frames} frames for {rep.best_epoch} "
            f"epochs, not validated (--no-validate); {_recovery_line(rep.recovery)}; report "
            f"{result.figure}",
            highlight=False,
        )
        return
    corr = "-" if rep.val_correlation is None else f"{rep.val_correlation:.3f}"
    kept = (
        f"trained again on every frame for {rep.best_epoch} epochs"
        if rep.refit_all_frames
        else f"best epoch {rep.best_epoch}"
    )
    console.print(
        f"{result.model}: {rep.train_frames} training / {rep.val_frames} validation frames, "
        f"{kept}; validation RMSE {rep.val_rmse:.4f} (baseline "
        f"{rep.baseline_mse**0.5:.4f}), MAE {rep.val_mae:.4f}, correlation {corr}; "
        f"{_recovery_line(rep.recovery)}; report {result.figure}",
        highlight=False,
    )


def _recovery_line(r: RecoveryRecord | None) -> str:
    """How the recovery views were made, or why there were none."""
    if r is None:
        return "no recovery views (no camera geometry, or turned off): horizontal shifts"
    return (
        f"recovery views up to {r.max_lateral_m:g} m / {r.max_yaw_deg:g} deg "
        f"(camera {r.camera_height_m:.2f} m high, look-ahead {r.lookahead_m:g} m)"
    )


@ads_app.command("export")
def export(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    onnx: Annotated[
        bool, typer.Option("--onnx", hidden=True, help="Export to ONNX (the only format).")
    ] = True,
    out: Annotated[
        Path | None, typer.Option(help="Output file (default WS/ads/dave2.onnx).")
    ] = None,
) -> None:
    """Export the trained model to ONNX and check onnxruntime against torch.

    Example: cam2sim ads export ws
    """
    from cam2sim.stages.ads import export_ads  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    del onnx  # ONNX is the one export format; the flag mirrors the documented command
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = export_ads(ws, out=out, progress=sink)
    rep = result.report
    console.print(
        f"{result.path}: opset {rep.opset}, max |torch - onnxruntime| "
        f"{rep.max_abs_diff_random:.2e} on {rep.random_inputs} random inputs; {result.report_path}",
        highlight=False,
    )


@ads_app.command("serve")
def serve(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    model: Annotated[
        str | None,
        typer.Option(help="Model file or policy spec (default: WS/ads/dave2.onnx)."),
    ] = None,
    host: Annotated[str, typer.Option(help="Interface to bind.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port (0: any free).")] = 5090,
    allow_remote: Annotated[
        bool, typer.Option("--allow-remote", help="Allow binding a non-loopback interface.")
    ] = False,
    clip: Annotated[float | None, typer.Option(help="Clip steering replies to +-CLIP.")] = None,
) -> None:
    """Serve the model over TCP with the published tool's protocol (and a lossless variant).

    Each message is a 4-byte big-endian length and a payload; a request is a JPEG/PNG image
    (or raw RGB), the reply "steering,throttle". Stop with Ctrl-C.

    Example: cam2sim ads serve ws --port 5090
    """
    from cam2sim.ads.serve import serve as run_server  # noqa: PLC0415 -- lazy: imports cv2

    try:
        ws = Workspace.open(workspace)
        spec = model or str(ws.ads_files.onnx)
        if model is None and not ws.ads_files.onnx.is_file():
            msg = (
                f"{ws.ads_files.onnx} does not exist; run `cam2sim ads train` and "
                "`cam2sim ads export` first, or pass --model"
            )
            raise error_exit(Cam2SimError(msg))

        def ready(server: object) -> None:
            console.print(
                f"serving {spec} on {getattr(server, 'address', '?')} (Ctrl-C to stop)",
                highlight=False,
            )

        run_server(spec, host=host, port=port, allow_remote=allow_remote, clip=clip, on_ready=ready)
    except KeyboardInterrupt:
        console.print("server stopped")
