"""The HTML report: self-contained, every section present, renders in headless Chromium."""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from cam2sim.cli.report_cmd import report
from cam2sim.core.config import Config, RecordingConfig
from cam2sim.core.workspace import LEGACY_PIPELINE_FILE, Workspace
from cam2sim.report.html import SECTION_IDS, write_report
from cam2sim.scenario.synthetic import StreetSpec
from cam2sim.splat.evaluate import SplatEval
from cam2sim.stages.evaluate import EvaluateOptions, evaluate_workspace
from cam2sim.stages.runs import DriveOptions, ReplayOptions, drive, replay
from conftest import (
    has_egl,
    launch_chromium,
    playwright_with_chromium,
    street_workspace,
    truth_workspace,
)

#: Where the Chromium test keeps its full-page screenshot (CI uploads ``test-artifacts/``).
SCREENSHOT_ENV = "CAM2SIM_REPORT_SCREENSHOT"
# Attributes that make a browser fetch something; every value must be a data URI or a fragment.
RESOURCE = re.compile(r"""\b(?:src|href|poster|data|action)\s*=\s*["']?([^"'\s>]*)""")


def _workspace(root: Path) -> Workspace:
    return street_workspace(root, StreetSpec(length_m=30.0, radius_m=60.0))


def _image_metrics(ws: Workspace, frames: Path) -> None:
    """Score the replay's frames against themselves: the images and semantic JSON artifacts."""
    from cam2sim.metrics.image_quality import (
        ImageQualityOptions,
        evaluate_image_folders,
        write_image_quality,
    )
    from cam2sim.metrics.semantic import evaluate_semantic_folders

    quality = evaluate_image_folders(frames, frames, options=ImageQualityOptions(lpips_net=None))
    write_image_quality(quality, ws.report_dir / "images")
    semantic = ws.report_dir / "semantic"
    result = evaluate_semantic_folders(frames, frames, comparison_dir=semantic / "comparison")
    result.save(semantic / "semantic.json")
    from cam2sim.metrics.steering_agreement import steering_agreement

    names = ["000000", "000001", "000002"]
    agreement = steering_agreement(
        "images", "dave2.onnx", names, [0.0, 1.0, -1.0], [0.1, 0.7, -1.0]
    )
    agreement.save(ws.report_dir / "images" / "steering.json")


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, Path, bool]:
    ws = _workspace(tmp_path_factory.mktemp("report") / "ws")
    drive(ws, options=DriveOptions(camera="none", runs=2))
    rendered = has_egl()
    if rendered:
        run = replay(ws, options=ReplayOptions(cameras=("raster",), image_size=(160, 100)))
        _image_metrics(ws, run.folder / "frames" / "raster")
    evaluate_workspace(ws, options=EvaluateOptions(replay_runs=()))  # the report only reads
    calls: list[tuple[str, int, int | None]] = []
    path = write_report(ws, progress=lambda *a: calls.append(a))
    assert calls[-1][1] == calls[-1][2]
    return ws, path, rendered


def _no_external_resources(html: str) -> None:
    assert "http://" not in html
    assert "https://" not in html
    assert RESOURCE.findall(html)
    assert [v for v in RESOURCE.findall(html) if not v.startswith(("data:", "#"))] == []
    assert "url(" not in html


def test_report_embeds_every_section_and_no_external_resource(
    built: tuple[Workspace, Path, bool],
) -> None:
    ws, path, rendered = built
    assert path == ws.report_dir / "report.html"
    html = path.read_text(encoding="utf-8")
    for sid in SECTION_IDS:
        assert html.count(f'<section id="{sid}">') == 1
    _no_external_resources(html)
    assert html.count('src="data:image/png;base64,') >= 3  # map, lateral offset, steering
    assert "drive-none" in html  # the behaviour table's method row
    assert "Min-Fréchet" in html
    assert not list(ws.report_dir.glob(".*.tmp"))
    if rendered:
        assert 'src="data:image/jpeg;base64,' in html  # chosen frames and the strip
        assert 'src="data:video/webm;base64,' in html  # a clip browsers can play
        assert "mIoU" in html
        semantic = html.split('<section id="semantic">')[1].split("</section>")[0]
        assert semantic.count('alt="labels ') == 3  # the comparison pictures already written
        assert "PSNR dB" in html
        # DAVE-2 on the rendered frames against the recorded ones: the gap and where it peaks.
        assert "DAVE-2 steering gap |rendered - recorded|, mean (units)</td><td>0.133" in html
        assert "0.300 (000001)" in html
        assert "not available" not in html.split('id="frames"')[1]
    else:
        assert "cam2sim replay" in html


def test_the_tables_are_exported_as_csv_and_latex_with_the_htmls_numbers(
    built: tuple[Workspace, Path, bool],
) -> None:
    import csv
    import html as html_lib

    ws, path, rendered = built
    page = html_lib.unescape(path.read_text(encoding="utf-8"))
    tables = ws.report_dir / "tables"
    names = {"behaviour"} | ({"semantic"} if rendered else set())
    assert names <= {p.stem for p in tables.glob("*.csv")}
    for name in names:
        rows = list(csv.reader((tables / f"{name}.csv").read_text(encoding="utf-8").splitlines()))
        assert len(rows) >= 2
        for row in rows[1:]:  # every data row is a row of the HTML, cell for cell
            assert "<tr><td>" + "</td><td>".join(row) + "</td></tr>" in page
        tex = (tables / f"{name}.tex").read_text(encoding="utf-8")
        assert "\\begin{tabular}" in tex
        assert f"\\label{{tab:{name}}}" in tex
        assert tex.count(" \\\\\n") == len(rows)  # header and data rows
        assert "%" not in tex.replace("\\%", "")  # escaped for LaTeX


def test_one_behaviour_table_one_name_per_method_and_labels_that_match_the_frames(
    built: tuple[Workspace, Path, bool],
) -> None:
    _ws, path, rendered = built
    html = path.read_text(encoding="utf-8")
    assert html.count("Behaviour per method") == 1
    assert "Drive behaviour per method" not in html  # the same numbers twice, before
    assert "no camera" in html  # the paper's names, not the runs' method ids, head the table
    behaviour = html.split('<section id="behaviour">')[1].split("</section>")[0]
    assert "<th>drive-none</th>" not in behaviour
    assert "Frames: real | splat | simulator" not in html  # a heading that named no real order
    if rendered:
        frames = html.split('<section id="frames">')[1].split("</section>")[0]
        # The replay rendered the raster camera beside the recorded frame: named Sim, in order.
        assert "side by side: recorded (left, where there is a recorded frame) | Sim" in frames
        assert "raster" not in frames.split("<figure>")[0].split("</h3>")[-1]


def test_latex_escapes_what_latex_reads_as_commands() -> None:
    from cam2sim.report.exports import latex_escape

    assert latex_escape("failure rate % & runs_#1 ± 2") == (
        "failure rate \\% \\& runs\\_\\#1 $\\pm$ 2"
    )


def test_a_bare_workspace_says_what_to_run_in_every_section(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=["x.bag"])))
    out = tmp_path / "elsewhere" / "r.html"
    result = CliRunner().invoke(_app(), [str(ws.root), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert str(out) in result.output.replace("\n", "")
    html = out.read_text(encoding="utf-8")
    sections = re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL)
    assert [s for s, _ in sections] == list(SECTION_IDS)
    for sid, body in sections[1:]:
        assert "not available: run <code>cam2sim " in body, sid
    _no_external_resources(html)
    # Inputs read as text, not JSON.
    assert "<td>recording bags</td><td>x.bag</td>" in html
    assert "[&quot;" not in html


def test_the_latest_pipeline_steps_are_listed_and_a_failed_one_is_a_warning(
    tmp_path: Path,
) -> None:
    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=["x.bag"])))
    ws.runs_dir.mkdir(parents=True, exist_ok=True)
    steps = {
        "replay": {"state": "done", "seconds": 18.7, "finished": "2026-11-22T06:22:45"},
        "drive": {"state": "failed", "seconds": 2.0, "message": "policy missing", "finished": "x"},
    }
    # An older cam2sim's pipeline state: merged into the manifest, the one state store.
    legacy = ws.runs_dir / LEGACY_PIPELINE_FILE
    legacy.write_text(json.dumps({"steps": steps}), encoding="utf-8")
    html = write_report(ws).read_text(encoding="utf-8")
    summary = re.search(r'<section id="summary">(.*?)</section>', html, re.DOTALL)
    assert summary is not None
    body = summary.group(1)
    assert "Pipeline steps" in body
    assert "<caption>Stages</caption>" not in body  # one table of what ran, not two
    assert "<td>replay</td><td>done</td><td>2026-11-22 06:22:45</td><td>18.7</td>" in body
    assert "step drive failed: policy missing" in body
    assert not legacy.exists()
    assert ws.read_manifest().steps["drive"].message == "policy missing"


def _app() -> typer.Typer:
    app = typer.Typer()
    app.command()(report)
    return app


def _screenshot_path(config: pytest.Config) -> Path:
    """``$CAM2SIM_REPORT_SCREENSHOT``, else ``test-artifacts/report.png`` in the repository."""
    given = os.environ.get(SCREENSHOT_ENV)
    return Path(given) if given else config.rootpath / "test-artifacts" / "report.png"


def test_report_renders_in_headless_chromium(
    built: tuple[Workspace, Path, bool], request: pytest.FixtureRequest
) -> None:
    sync_api = playwright_with_chromium()
    _, path, _ = built
    shot = _screenshot_path(request.config)
    shot.parent.mkdir(parents=True, exist_ok=True)
    shot.unlink(missing_ok=True)
    sizes: dict[str, float] = {}
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = launch_chromium(pw)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.on("request", lambda r: requests.append(r.url))
            page.goto(path.as_uri(), wait_until="load")
            for sid in SECTION_IDS:
                section = page.locator(f"section#{sid}")
                section.scroll_into_view_if_needed()
                assert section.is_visible(), sid
                box = section.bounding_box()
                sizes[sid] = 0.0 if box is None else box["width"] * box["height"]
            loaded = page.evaluate(
                "Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)"
            )
            videos = page.locator("video").count()
            if videos:  # the embedded clip decodes: its size is known once metadata loaded
                page.wait_for_function(
                    "Array.from(document.querySelectorAll('video'))"
                    ".every(v => v.readyState >= 1 && v.videoWidth > 0)",
                    timeout=10_000,
                )
            page.screenshot(path=str(shot), full_page=True)
            height = page.evaluate("document.documentElement.scrollHeight")
        finally:
            browser.close()
    assert errors == []
    assert loaded
    assert all(u.startswith(("file:", "data:")) for u in requests), requests
    assert all(area > 1000 for area in sizes.values()), sizes  # every section takes room
    assert shot.stat().st_size > 10_000
    import cv2

    image = cv2.imread(str(shot), cv2.IMREAD_COLOR)
    assert image is not None
    assert image.shape[0] >= height - 1  # the whole page, not the first screen


def _splat_eval(psnr: float) -> SplatEval:
    """A held-out evaluation with a ground-truth envelope (on path, +-2 m, a yaw turn)."""
    from cam2sim.splat.evaluate import HeldOutFrame, TruthEnvelope, TruthScore, summarise

    def row(lateral: float, yaw: float, drop: float) -> TruthScore:
        return TruthScore(
            lateral_m=lateral, yaw_deg=yaw, psnr_db=summarise([psnr - drop, psnr - 2 * drop]),
            ssim=summarise([0.85 - drop / 50]), lpips=summarise([0.3 + drop / 20]),
            coverage=summarise([0.5 + abs(lateral) / 5]),
        )  # fmt: skip

    frame = HeldOutFrame(index=8, psnr_db=psnr, ssim=0.83, lpips=0.35, coverage=0.5, chunks={})
    truth = [row(0.0, 0.0, 0.0), row(-2.0, 0.0, 3.0), row(2.0, 0.0, 4.0), row(0.0, 5.0, 0.5)]
    return SplatEval(
        models_dir="models", n_held_out=1, psnr_db=summarise([psnr]), ssim=summarise([0.83]),
        lpips=summarise([0.35]), lpips_net="alex", lower_fraction=0.5, frames=[frame],
        offsets=[], truth=TruthEnvelope(frames=[8], lpips_net="alex", scores=truth),
    )  # fmt: skip


def test_the_report_shows_the_splat_envelope_and_an_unfit_splat_plainly(tmp_path: Path) -> None:
    from cam2sim.metrics.splat_gate import gate_run, path_quality

    ws = _workspace(tmp_path / "ws")
    evaluation = _splat_eval(21.3)
    evaluation.save(ws.splat_dir / "eval.json")
    (run,) = drive(ws, options=DriveOptions(camera="none", runs=1))
    meta = json.loads((run.folder / "run.json").read_text(encoding="utf-8"))
    quality = path_quality([0.2, 0.3, 0.25], evaluation)  # as a splat drive records it
    meta |= {
        "method": "drive-splat",
        "splat_quality": quality.model_dump(mode="json"),
        "splat_gate": gate_run(quality).model_dump(mode="json"),
    }
    (run.folder / "run.json").write_text(json.dumps(meta), encoding="utf-8")
    evaluate_workspace(ws)  # the report only reads the evaluate stage's metrics
    html = write_report(ws).read_text(encoding="utf-8")
    sections = dict(re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL))
    behaviour, splat = sections["behaviour"], sections["splat"]
    assert "<th>splat (unfit)</th>" in behaviour
    assert "splat (unfit): splat under-trained: held-out 21.3 dB &lt; 25 dB" in behaviour
    assert "Validity envelope, measured" in splat
    assert "<td>on path</td><td>21.30</td><td>0.850</td>" in splat
    assert "<td>2 m right</td>" in splat  # words, not a sign to decode
    assert "<td>turned 5° left</td>" in splat
    assert splat.count('src="data:image/png;base64,') == 1  # the envelope plot
    assert "splat: unfit (1/1 runs)" in splat
    assert "drive-splat" not in splat + behaviour  # the paper's name, everywhere
    assert "its runs fail the splat quality gate" in sections["summary"]
    assert "unfit (0.25 / 0.30)" in sections["runs"]
    evaluation.model_copy(update={"truth": None}).save(ws.splat_dir / "eval.json")
    html = write_report(ws).read_text(encoding="utf-8")
    splat = dict(re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL))["splat"]
    assert "Not scored against a ground truth" in splat
    assert "Validity envelope, measured" not in splat


def test_the_report_says_how_each_splat_chunk_was_trained(tmp_path: Path) -> None:
    import cv2
    import numpy as np

    from cam2sim.splat.chunk_header import ChunkHeader, ViewRecord, outliers_path

    ws = _workspace(tmp_path / "ws")
    _splat_eval(27.0).save(ws.splat_dir / "eval.json")
    models = ws.splat_dir / "models"
    models.mkdir(parents=True)

    def view(i: int, correction: list[float] | None) -> ViewRecord:
        return ViewRecord(
            index=i, progress_m=float(i), position=[0.0, float(i), 1.5], forward=[0, 1, 0],
            correction=correction,
        )  # fmt: skip

    common = {
        "start_m": 0.0, "end_m": 10.0, "sh_degree": 3, "n_sky": 100, "scene_scale": 10.0,
        "sky_radius_m": 500.0, "background": [0.0, 0.0, 0.0], "backend": "gsplat",
    }  # fmt: skip
    ChunkHeader(
        chunk_id=0, n_gaussians=1_000_000, steps=30_000, stopped="max_steps",
        notes=["densification mcmc, initial opacity 0.5, sky-share weight 0"],
        antialiased=True, train_views=[view(0, None), view(1, None)],
        val_history=[(1000, 20.0, 0.70), (2000, 24.0, 0.80), (3000, 25.0, 0.85)], **common,
    ).save(models / "chunk_00.json")  # fmt: skip
    # Pose refinement: turns of 1 and 3 degrees, shifts of 0.1 and 0.3 units.
    turn = np.radians([1.0, 3.0])
    ChunkHeader(
        chunk_id=1, n_gaussians=500_000, steps=12_000, stopped="plateau",
        train_views=[view(0, [0, 0, turn[0], 0.1, 0, 0]), view(1, [0, 0, turn[1], 0, 0.3, 0])],
        **common,
    ).save(models / "chunk_01.json")  # fmt: skip
    picture = np.zeros((24, 64, 3), np.uint8)
    outliers_path(models / "chunk_01.pt").write_bytes(cv2.imencode(".jpg", picture)[1].tobytes())
    html = write_report(ws).read_text(encoding="utf-8")
    splat = dict(re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL))["splat"]
    assert "Training, per chunk model" in splat
    assert "<td>0</td><td>30,000</td><td>max_steps</td><td>1,000,000</td>" in splat
    assert "densification mcmc, initial opacity 0.5, sky-share weight 0; antialiased" in splat
    assert "<td>classic</td>" in splat  # chunk 1: no notes, the classic filter
    assert "<td>off</td>" in splat  # chunk 0: no pose refinement
    assert "0.2 / 0.3 units, 2.00 / 3.00°" in splat
    assert "chunk 1: pixels the robust weighting left out" in splat
    assert splat.count('src="data:image/jpeg;base64,') == 1
    # Chunk 0's validations make a training curve; chunk 1 (no history) is left out of it.
    assert 'alt="held-in PSNR and SSIM over the training steps, per chunk model"' in splat
    loaded = ChunkHeader.load(models / "chunk_00.json")
    assert loaded.val_history == [(1000, 20.0, 0.70), (2000, 24.0, 0.80), (3000, 25.0, 0.85)]


def test_the_training_figure_draws_each_chunk_with_a_history() -> None:
    from cam2sim.report.splat_figures import training_figure
    from cam2sim.splat.chunk_header import ChunkHeader

    common = {
        "start_m": 0.0, "end_m": 10.0, "sh_degree": 3, "n_sky": 0, "n_gaussians": 10,
        "scene_scale": 1.0, "sky_radius_m": 50.0, "background": [0.0, 0.0, 0.0],
        "train_views": [],
    }  # fmt: skip
    headers = [
        ChunkHeader(chunk_id=0, val_history=[(100, 18.0, 0.6), (200, 21.5, 0.7)], **common),
        ChunkHeader(chunk_id=1, **common),  # trained before histories were kept
        ChunkHeader(chunk_id=2, val_history=[(100, 19.0, 0.65)], **common),
    ]
    fig = training_figure(headers)
    psnr_ax, ssim_ax = fig.axes
    assert [line.get_label() for line in psnr_ax.lines] == ["chunk 0", "chunk 2"]
    assert list(psnr_ax.lines[0].get_ydata()) == [18.0, 21.5]
    assert list(ssim_ax.lines[1].get_xdata()) == [100]


def test_the_report_reads_the_drive_metrics_and_says_which_command_writes_them(
    tmp_path: Path,
) -> None:
    ws = _workspace(tmp_path / "ws")
    drive(ws, options=DriveOptions(camera="none", runs=1))
    html = write_report(ws).read_text(encoding="utf-8")
    sections = dict(re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL))
    command = f"not available: run <code>cam2sim evaluate workspace {ws.root}</code>"
    assert command in sections["behaviour"]
    assert command in sections["runs"]
    assert not (ws.report_dir / "drive").exists()  # the report computed nothing
    evaluate_workspace(ws)
    drive(ws, options=DriveOptions(camera="none", runs=1, seed=5))  # not scored yet
    html = write_report(ws).read_text(encoding="utf-8")
    sections = dict(re.findall(r'<section id="(\w+)">(.*?)</section>', html, re.DOTALL))
    assert "Min-Fréchet" in sections["behaviour"]
    assert "1 drive run(s) not in" in sections["summary"]


def test_an_imported_workspace_names_its_images_as_its_input(tmp_path: Path) -> None:
    import cv2

    from cam2sim.stages.image_import import import_images

    (tmp_path / "frames").mkdir()
    for k in range(3):
        cv2.imwrite(str(tmp_path / "frames" / f"{k:06d}.png"), np.zeros((8, 8, 3), np.uint8))
    import_images(tmp_path / "ws", tmp_path / "frames")
    html = write_report(Workspace.open(tmp_path / "ws")).read_text(encoding="utf-8")
    assert f"<td>imported</td><td>{tmp_path / 'frames'}</td>" in html
    assert "recording bags" not in html


def test_the_ground_truth_worlds_title_and_notes_are_inputs(tmp_path: Path) -> None:
    from cam2sim.render.truth import TruthWorld, truth_world_path

    ws = truth_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    html = write_report(ws).read_text(encoding="utf-8")
    assert "ground-truth world" not in html  # a world without a title says nothing
    path = truth_world_path(ws.root)
    notes = ("no route on residential roads alone: <main roads> too", "route picked among 25")
    titled = TruthWorld.load(path).model_copy(
        update={"title": "Lerchenauer Straße", "notes": notes}
    )
    titled.save(path)
    assert TruthWorld.load(path).notes == notes  # written and read back
    html = write_report(ws).read_text(encoding="utf-8")
    assert "<td>ground-truth world</td><td>Lerchenauer Straße</td>" in html
    assert (
        "<td>world note</td><td>no route on residential roads alone: &lt;main roads&gt; too" in html
    )
    assert html.count("<td>world note</td>") == 2


def test_frame_clips_are_written_without_ffmpegs_codec_warning(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """OpenCV's FFmpeg backend prints "tag 'VP80' is not supported" on opening a WebM writer."""
    import cv2

    from cam2sim.report.frames_section import webm

    files = []
    for k in range(4):
        path = tmp_path / f"{k:06d}.png"
        cv2.imwrite(str(path), np.full((48, 64, 3), 40 * k, np.uint8))
        files.append(path)
    print("before", file=sys.stderr, flush=True)  # noqa: T201
    clip = webm(files)
    print("after", file=sys.stderr, flush=True)  # noqa: T201
    assert clip is not None
    assert clip[:4] == b"\x1a\x45\xdf\xa3"  # a Matroska/WebM file
    err = capfd.readouterr().err
    assert "FFMPEG" not in err
    assert "before" in err
    assert "after" in err  # stderr works again after the writer opened


def test_the_headline_says_what_its_columns_hold_and_warns_of_a_starved_splat(
    tmp_path: Path,
) -> None:
    from cam2sim.splat.chunk_header import ChunkHeader

    ws = _workspace(tmp_path / "ws")
    drive(ws, options=DriveOptions(camera="none", runs=2))
    evaluate_workspace(ws, options=EvaluateOptions(replay_runs=()))
    models = ws.splat_dir / "models"
    models.mkdir(parents=True)
    for k, stopped in enumerate(("plateau", "time")):
        ChunkHeader(
            chunk_id=k, start_m=0.0, end_m=10.0, sh_degree=0, n_gaussians=10, n_sky=0,
            scene_scale=1.0,
            sky_radius_m=100.0, background=[0.0, 0.0, 0.0], train_views=[], steps=900 + k,
            backend="gsplat", stopped=stopped,
        ).save(models / f"chunk_{k:02d}.json")  # fmt: skip
    _splat_eval(26.0).model_copy(update={"psnr_db_raw": _splat_eval(22.0).psnr_db}).save(
        ws.splat_dir / "eval.json"
    )
    ws.ads_dir.mkdir(parents=True, exist_ok=True)
    (ws.ads_dir / "train_report.png").write_bytes(_png_bytes())
    html = write_report(ws).read_text(encoding="utf-8")
    behaviour = html.split('<section id="behaviour">')[1].split("</section>")[0]
    assert "<h3>The system under test</h3>" in behaviour
    assert 'alt="DAVE-2 training' in behaviour
    assert "Real has one run more than the closed-loop columns: the recorded drive" in behaviour
    assert "Real in this workspace is the recorded drive" in behaviour  # no truth world here
    assert "2 chunk(s) trained with gsplat, 900/901 steps, stopped by plateau/time" in behaviour
    assert "22.0 dB without its colour transform" in behaviour
    warnings = html.split("<h3>Warnings</h3>")[1]
    assert "stopped on their time budget" in warnings
    assert "the transform, not the model" in warnings


def _png_bytes() -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    assert ok
    return data.tobytes()


def test_plots_have_one_legend_entry_and_colour_per_method(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from cam2sim.report import drive_figures

    seen: dict[str, tuple[list[str], str, dict[str, set[str]]]] = {}

    def keep(fig: object, path: Path) -> None:
        ax = fig.axes[0]  # type: ignore[attr-defined]
        legend = ax.get_legend()
        labels = [t.get_text() for t in legend.get_texts()] if legend else []
        colours: dict[str, set[str]] = {}
        for line in ax.get_lines():
            colours.setdefault(str(line.get_label()), set()).add(str(line.get_color()))
        seen[path.name] = (labels, ax.get_ylabel(), colours)

    monkeypatch.setattr(drive_figures, "_save", keep)
    ws = _workspace(tmp_path / "ws")
    drive(ws, options=DriveOptions(camera="none", runs=3))
    evaluate_workspace(ws, options=EvaluateOptions(replay_runs=()))
    labels, ylabel, _ = seen["lateral_offset.png"]
    assert labels == ["real corridor", "Real", "no camera"]  # not one entry per run id
    assert "+ = left" in ylabel  # the sign convention on the axis
    steering_labels, steering_y, _ = seen["steering.png"]
    assert len(steering_labels) == len(set(steering_labels))
    assert "+ = left" in steering_y


def test_the_splat_section_shows_the_worst_median_and_best_held_out_frames(
    tmp_path: Path,
) -> None:
    import cv2

    from cam2sim.splat.evaluate import HeldOutFrame

    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=["x.bag"])))
    frames = [
        HeldOutFrame(index=i, psnr_db=p, ssim=0.8, lpips=None, coverage=0.1, chunks={})
        for i, p in ((8, 27.0), (16, 31.0), (24, 22.0), (32, 29.0))
    ]
    _splat_eval(26.0).model_copy(update={"frames": frames}).save(ws.splat_dir / "eval.json")
    for sub, ext in (("prep/images", "png"), ("renders", "webp")):
        (ws.splat_dir / sub).mkdir(parents=True)
        for f in frames:
            cv2.imwrite(str(ws.splat_dir / sub / f"{f.index:06d}.{ext}"), np.zeros((20, 32, 3)))
    html = write_report(ws).read_text(encoding="utf-8")
    splat = html.split('<section id="splat">')[1].split("</section>")[0]
    assert "worst: frame 24, 22.0 dB" in splat
    assert "median: frame 32, 29.0 dB" in splat  # the upper median of four
    assert "best: frame 16, 31.0 dB" in splat


def test_a_failed_drive_shows_its_last_frame_and_each_method_its_own_frames(
    tmp_path: Path,
) -> None:
    import cv2

    ws = _workspace(tmp_path / "ws")
    runs = drive(ws, options=DriveOptions(camera="none", runs=2))
    for run, camera in zip(runs, ("raster", "splat"), strict=True):  # frames as if seen
        meta = json.loads((run.folder / "run.json").read_text(encoding="utf-8"))
        meta["camera"] = camera
        (run.folder / "run.json").write_text(json.dumps(meta), encoding="utf-8")
        frames = run.folder / "frames" / camera
        frames.mkdir(parents=True)
        for k in range(3):
            cv2.imwrite(str(frames / f"{k:06d}.png"), np.full((10, 16, 3), 40 * k, np.uint8))
    events = {"events": [{"kind": "collision", "t": 3.2, "reason": "hit parked vehicle pv_1"}]}
    (runs[0].folder / "events.json").write_text(json.dumps(events), encoding="utf-8")
    html = write_report(ws).read_text(encoding="utf-8")
    frames_html = html.split('<section id="frames">')[1].split("</section>")[0]
    assert "closed loop, splat: what DAVE-2 saw" in frames_html
    assert "closed loop, Sim: what DAVE-2 saw" in frames_html
    assert frames_html.index("closed loop, splat") < frames_html.index("closed loop, Sim")
    assert "the last frame before it failed: collision at 3.2 s: hit parked vehicle pv_1" in (
        frames_html
    )
