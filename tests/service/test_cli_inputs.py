"""The rough edges a new user of ``dlo`` hits (issue 20): Ctrl-C exit statuses, oversized
and damaged images, decompression-bomb masks, HSV boxes without HSV segmentation,
``--params``, the JSON on stdout, what a folder holds besides images, help screens, and a
zenoh configuration that does not exist."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from schemas import Detection, DetectParams
from service.cli import app
from service.http.inputs import parse_params
from service.perception import detect
from service.runtime.errors import RequestError
from tests.helpers import blank_png, wait_until
from tests.service.test_cli import ANSI_ESCAPE, draw_cables, error_lines, stderr_lines, write_scene
from tests.service.test_video import write_video

DLO = [sys.executable, "-c", "from service.cli import main; main()"]
PEAK_RSS = (
    "import resource, sys\n"
    "from service.cli import main\n"
    "try:\n"
    "    main()\n"
    "finally:\n"
    "    print('peak_rss_kb', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)"
)
"""``dlo`` that reports its own peak memory on its last stderr line."""

runner = CliRunner()


def run_dlo(*args: str | Path, columns: int = 100):
    env = {"COLUMNS": str(columns)}
    return runner.invoke(app, [str(arg) for arg in args], prog_name="dlo", env=env)


def run_process(*args: str | Path, **options) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*DLO, *map(str, args)], capture_output=True, text=True, timeout=300, **options
    )


@pytest.fixture(scope="module")
def scene_png(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scene(tmp_path_factory.mktemp("scene") / "scene.png")


# --- Ctrl-C --------------------------------------------------------------------------------


def interrupt_when(command: list[str], ready, tmp_path: Path) -> tuple[int, str]:
    """Start ``dlo`` with ``command``, send SIGINT once ``ready()`` holds; status, stderr."""
    stderr = tmp_path / "stderr.txt"
    with stderr.open("w") as sink:
        process = subprocess.Popen([*DLO, *command], stdout=subprocess.DEVNULL, stderr=sink)
        try:
            wait_until(lambda: ready() or process.poll() is not None, "the first output", 120)
            assert process.poll() is None, "the run ended before it could be interrupted"
            process.send_signal(signal.SIGINT)
            status = process.wait(timeout=60)
        finally:
            if process.poll() is None:
                process.kill()
    return status, ANSI_ESCAPE.sub("", stderr.read_text())


def test_an_interrupted_folder_batch_exits_130(tmp_path: Path) -> None:
    shots = tmp_path / "shots"
    shots.mkdir()
    for index in range(80):
        image, _ = draw_cables(640, 480, 3, seed=index)
        assert cv2.imwrite(str(shots / f"shot{index:02d}.png"), image)
    out = tmp_path / "out"
    status, stderr = interrupt_when(
        ["detect", str(shots), "--out-dir", str(out)], lambda: any(out.glob("*.json")), tmp_path
    )
    assert status == 130, stderr
    assert "image(s) processed" in stderr and "(interrupted)" in stderr
    assert 1 <= len(list(out.glob("*.json"))) < 80


def test_an_interrupted_video_exits_130(tmp_path: Path) -> None:
    clip = write_video(tmp_path / "clip.mp4", frames=400)
    out = tmp_path / "out"
    jsonl = out / "clip.jsonl"
    status, stderr = interrupt_when(
        ["detect", str(clip), "--out-dir", str(out)],
        lambda: jsonl.exists() and jsonl.stat().st_size > 0,
        tmp_path,
    )
    assert status == 130, stderr
    assert "(interrupted)" in stderr
    lines = jsonl.read_text().splitlines()
    assert 1 <= len(lines) < 400
    assert all(json.loads(line)["detection"] for line in lines)  # whole lines only


# --- images the decoders refuse -------------------------------------------------------------


def damaged_png() -> bytes:
    """A small PNG whose pixel data fails its checksum."""
    data = bytearray(cv2.imencode(".png", np.full((20, 30, 3), 90, np.uint8))[1].tobytes())
    at = data.index(b"IDAT")
    length = int.from_bytes(data[at - 4 : at], "big")
    data[at + 4 + length : at + 8 + length] = b"\0\0\0\0"
    return bytes(data)


def test_oversized_and_damaged_images_are_one_line_errors_without_libpng_lines(
    tmp_path: Path, scene_png: Path
) -> None:
    files = {
        "thin.png": blank_png(1, 5_000_000, bit_depth=8),  # valid, decodes to 5 MP
        "huge.png": blank_png(40_000, 40_000),  # 1.6 gigapixels
        "damaged.png": damaged_png(),
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    good = tmp_path / "good.png"
    good.write_bytes(scene_png.read_bytes())
    completed = run_process(
        "detect", *(tmp_path / name for name in files), good, "--out-dir", tmp_path / "out"
    )
    assert completed.returncode == 1
    lines = [line for line in ANSI_ESCAPE.sub("", completed.stderr).splitlines() if line]
    assert lines[-1].startswith("1 of 4 image(s) processed")
    errors = lines[:-1]
    assert len(errors) == 3 and all(line.startswith("error: ") for line in errors), lines
    thin, huge, damaged = errors
    assert "thin.png: image is 1x5000000 px: too large" in thin
    assert "at most 1000000 px a side" in thin and "not an image" not in thin
    assert "huge.png: image is 40000x40000 px: too large to decode" in huge
    assert "damaged.png: damaged PNG file (libpng error: IDAT: CRC error)" in damaged
    assert "OpenCV(" not in completed.stderr and "Assertion" not in completed.stderr


def test_a_bomb_mask_is_refused_from_its_header(tmp_path: Path, scene_png: Path) -> None:
    """Refused before decoding: the run peaks no higher than one with a proper mask (the
    bomb would decode to 2.7 GB)."""

    def peak_mb(mask: Path) -> tuple[float, subprocess.CompletedProcess]:
        completed = subprocess.run(
            [sys.executable, "-c", PEAK_RSS, "detect", str(scene_png), "--mask", str(mask)],
            capture_output=True,
            text=True,
            timeout=300,
        )
        return int(completed.stderr.split()[-1]) / 1024, completed

    proper = tmp_path / "proper.png"
    _, drawn = draw_cables(320, 240, 2, seed=1)
    assert cv2.imwrite(str(proper), drawn.astype(np.uint8) * 255)
    baseline, completed = peak_mb(proper)
    assert completed.returncode == 0, completed.stderr
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(blank_png(30_000, 30_000))
    peak, completed = peak_mb(bomb)
    lines = ANSI_ESCAPE.sub("", completed.stderr).splitlines()
    assert completed.returncode == 1
    assert lines[0] == f"error: {bomb}: mask is 30000x30000 but the image is 320x240"
    assert peak < baseline + 100, f"peaked at {peak:.0f} MB, {baseline:.0f} with a proper mask"


# --- parameters -----------------------------------------------------------------------------


def test_an_hsv_box_without_hsv_segmentation_is_refused_everywhere(scene_png: Path) -> None:
    result = run_dlo("detect", scene_png, "--hsv-low", "0", "80", "60")
    assert result.exit_code == 2
    assert error_lines(result) == [
        "error: hsv_low/hsv_high apply only to segmentation 'hsv', and segmentation is "
        "'auto': set segmentation to hsv too"
    ]
    from starlette.datastructures import QueryParams

    with pytest.raises(RequestError) as refused:
        parse_params(QueryParams("hsv_high=20,255,255"))
    assert refused.value.status == 422 and "segmentation" in refused.value.message
    assert parse_params(QueryParams("segmentation=hsv&hsv_high=20,255,255")).hsv_high == (
        20,
        255,
        255,
    )
    # A saved DetectParams (defaults written out) still loads.
    assert DetectParams.model_validate_json(DetectParams().model_dump_json()) == DetectParams()


def test_detect_takes_every_parameter_with_params(tmp_path: Path, scene_png: Path) -> None:
    chosen = {"gap_curve": "natural", "max_gap": 120.0, "merge_cost_threshold": 0.5}
    result = run_dlo("detect", scene_png, "--params", json.dumps(chosen))
    assert result.exit_code == 0, result.stderr
    given = Detection.model_validate_json(result.stdout)
    expected = detect(cv2.imread(str(scene_png)), DetectParams(**chosen))
    assert given.model_dump(exclude={"timings_ms"}) == expected.model_dump(exclude={"timings_ms"})

    stored = tmp_path / "params.json"
    stored.write_text(json.dumps({"segment_length": 20}))
    result = run_dlo("detect", scene_png, "--params", stored, "--segment-length", "15")
    assert result.exit_code == 0, result.stderr
    assert Detection.model_validate_json(result.stdout).segment_length == 15  # option wins

    for bad, words in (('{"gap_curv": 1}', "gap_curv"), ("nofile.json", "neither")):
        result = run_dlo("detect", scene_png, "--params", bad)
        assert result.exit_code == 2
        (line,) = error_lines(result)
        assert line.startswith("error: --params: ") and words in line


def test_the_detection_on_stdout_has_one_line_per_chain(scene_png: Path) -> None:
    result = run_dlo("detect", scene_png)
    assert result.exit_code == 0, result.stderr
    detection = Detection.model_validate_json(result.stdout)
    lines = result.stdout.strip().splitlines()
    fields = len(Detection.model_fields)
    assert len(lines) <= 2 + fields + 2 * 2 + len(detection.chains) + len(detection.crossings)
    chain_lines = [line for line in lines if line.lstrip().startswith('{"id"')]
    assert len(chain_lines) == len(detection.chains)


# --- folders --------------------------------------------------------------------------------


def test_subfolders_and_broken_links_in_a_folder_are_mentioned(
    tmp_path: Path, scene_png: Path
) -> None:
    folder = tmp_path / "shots"
    (folder / "older").mkdir(parents=True)
    (folder / "a.png").write_bytes(scene_png.read_bytes())
    (folder / "b.png").symlink_to(tmp_path / "gone.png")
    (folder / "notes.txt").write_text("not an image, not mentioned")
    result = run_dlo("detect", folder, "--out-dir", tmp_path / "out")
    assert result.exit_code == 0, result.stderr
    warnings = [line for line in stderr_lines(result) if line.startswith("warning: ")]
    assert warnings == [
        f"warning: {folder / 'b.png'}: broken symbolic link (to {tmp_path / 'gone.png'}), skipped",
        f"warning: {folder / 'older'}: a folder, not searched (name it to include it)",
    ]


# --- help -----------------------------------------------------------------------------------

COMMANDS = (
    (),
    ("detect",),
    ("demo",),
    ("eval",),
    ("serve",),
    ("router",),
    ("bench",),
    ("feasibility",),
    ("ur3",),
    ("ur3", "plan"),
    ("ur3", "pick"),
    ("hexa",),
    ("hexa", "trial"),
)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda words: " ".join(words) or "dlo")
def test_help_shows_flags_and_arguments_plainly(command: tuple[str, ...]) -> None:
    result = run_dlo(*command, "--help")
    assert result.exit_code == 0, result.output
    text = ANSI_ESCAPE.sub("", result.output)
    assert "<bool>" not in text
    usage = next(line for line in text.splitlines() if "Usage:" in line)
    assert "{" not in usage and "}" not in usage, usage
    assert "(10.0)" not in text and "[default: (" not in text


def test_help_paragraphs_are_wrapped_by_the_terminal_not_the_docstring() -> None:
    text = ANSI_ESCAPE.sub("", run_dlo("detect", "--help", columns=200).output)
    assert "and cameras write one line of JSON per frame to" in text
    usage = ANSI_ESCAPE.sub("", run_dlo("ur3", "plan", "--help").output)
    assert "Usage: dlo ur3 plan [OPTIONS] IMAGE" in usage
    feasibility = " ".join(ANSI_ESCAPE.sub("", run_dlo("feasibility", "--help").output).split())
    assert "e.g. --direction 1 0 0" in feasibility.replace("│ ", "")


# --- dlo serve -------------------------------------------------------------------------------


def test_serve_refuses_to_start_with_a_missing_zenoh_configuration(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.json5"
    completed = run_process(
        "serve", env=dict(os.environ, DLO_ZENOH_CONFIG=str(missing), DLO_PORT="0")
    )
    assert completed.returncode == 2
    assert completed.stderr.strip() == (
        f"error: zenoh configuration {missing}: no such file (--zenoh-config, DLO_ZENOH_CONFIG)"
    )
