"""`dlo bench --quick` runs end to end, on one thread, and reports every table."""

import json
import subprocess
import sys

import pytest

DLO = [sys.executable, "-c", "from service.cli import main; main()"]


def test_dlo_bench_quick_runs_on_one_thread_and_reports_json(tmp_path):
    missing = tmp_path / "no-dataset"
    completed = subprocess.run(
        [*DLO, "bench", "--quick", "--json", "--dataset", str(missing)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    settings = results["settings"]
    assert set(settings["environment"].values()) == {"1"}
    assert settings["cv2_threads"] == 1 and settings["numba_threads"] == 1
    assert any(str(missing) in note for note in results["notes"])
    assert len(results["cases"]) == 4  # 1, 2, 3 cables and the larger size
    # Bright and textured backgrounds (no ariadne beside the missing folder).
    assert [case["case"].split()[0] for case in results["backgrounds"]] == ["bright", "textured"]
    cases = results["cases"] + results["backgrounds"]
    for case in cases + results["scaling_area"] + results["scaling_cables"]:
        stats = case["stages_ms"]
        assert set(stats) == {
            "segmentation",
            "skeleton",
            "contours",
            "fitting",
            "pruning",
            "merging",
            "total",
            "wall",
        }
        assert 0 < stats["total"]["p50"] <= stats["total"]["max"]
        assert case["fps"] > 0
    assert [row["cables"] for row in results["scaling_cables"]] == [1, 2, 3]
    assert [row["case"].split(",")[0] for row in results["lifting"]] == [
        "plane",
        "plane",
        "depth image",
    ]
    for row in results["lifting"]:
        assert row["joints"] > 0 and 0 < row["lift_ms"]["p50"] <= row["lift_ms"]["max"]
    assert [row["case"] for row in results["recording"]] == [
        "640x480, 1 cable(s)",
        "640x480, 3 cable(s)",
    ]
    for row in results["recording"]:
        for clock in ("wall_ms", "cpu_ms"):
            assert set(row[clock]) == {"jpeg", "image_message", "markers", "write"}
            assert 0 < row[clock]["write"]["p50"] <= row[clock]["write"]["max"]
        assert row["jpeg_kb"] > 0
    assert results["peak_rss_mb"] > 0


def test_dlo_bench_prints_tables_by_default(tmp_path):
    completed = subprocess.run(
        [*DLO, "bench", "--quick", "--dataset", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    for heading in (
        "one thread",
        "after warm-up",
        "p50 per stage",
        "scaling with image area",
        "a camera model",
        "a ROS 2 recording per frame",
    ):
        assert heading in completed.stdout
    assert "peak resident memory" in completed.stdout


def test_dlo_bench_startup_times_whole_processes(tmp_path):
    """Only the report's shape: the figures themselves are the benchmark's."""
    completed = subprocess.run(
        [*DLO, "bench", "--startup", "--quick", "--json", "--dataset", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    assert "generated" in results["image"]  # no photographs in an empty folder
    rows = {row["command"]: row for row in results["rows"]}
    assert {"dlo --help", "dlo version", "dlo detect IMAGE --out-dir DIR"} <= set(rows)
    assert len([name for name in rows if name.startswith("floor: ")]) == 5
    for row in rows.values():
        assert row["runs"] == 2
        assert 0 < row["min_s"] <= row["median_s"] <= row["max_s"]
        assert row["cpu_median_s"] > 0
    assert rows["dlo --help"]["target_s"] == 0.3
    assert len(results["load_average"]["before"]) == len(results["load_average"]["after"]) == 3
    assert results["bytecode_cached"] in (True, False)
    assert results["kernels"] == "jit: DLO_KERNELS=jit"  # as tests/conftest.py sets


def test_dlo_bench_recording_alone_reports_its_table_and_the_load(tmp_path):
    completed = subprocess.run(
        [*DLO, "bench", "--recording", "--quick", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    assert len(results["load_average"]) == 3
    assert [row["width"] for row in results["recording"]] == [640, 640]
    assert all(row["frames"] == 1 for row in results["recording"])


@pytest.mark.parametrize(
    "options",
    [["--startup", "--service"], ["--recording", "--service"], ["--recording", "--startup"]],
)
def test_dlo_bench_times_one_thing_at_a_time(options):
    completed = subprocess.run(
        [*DLO, "bench", *options], capture_output=True, text=True, timeout=60
    )
    assert completed.returncode == 2
    assert "give one" in completed.stderr


def bench(*options: str) -> subprocess.CompletedProcess:
    """``dlo bench OPTIONS`` in a process of its own, its output captured."""
    return subprocess.run([*DLO, "bench", *options], capture_output=True, text=True, timeout=300)


def test_dlo_bench_rings_times_scenes_of_many_small_rings():
    """The report's shape and the scenes: one chain per ring."""
    completed = bench("--rings", "9,40", "--json")
    assert completed.returncode == 0, completed.stderr
    rows = json.loads(completed.stdout)["rings"]
    assert [row["rings"] for row in rows] == [9, 40]
    assert [row["chains"] for row in rows] == [9, 40]
    assert [(row["width"], row["height"]) for row in rows] == [(120, 120), (280, 240)]
    assert all(row["total_ms"] > 0 for row in rows)
    refused = bench("--rings", "ten")
    assert refused.returncode == 2 and "--rings" in refused.stderr


def test_dlo_bench_bombs_reports_refusals_and_the_servers_memory():
    completed = bench("--bombs", "--quick", "--json")
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    assert [row["upload"] for row in results["rows"]] == ["image (raw body)", "mask (multipart)"]
    assert all(row["requests"] == 5 and row["p50_ms"] > 0 for row in results["rows"])
    memory = results["server_peak_rss_mb"]
    assert memory["after"] - memory["before"] < 64  # decoding one bomb: 2.7 GB


@pytest.mark.slow
def test_dlo_bench_tracking_times_frames_and_whole_processes():
    """The report's shape: per-frame rows (tracking beside detection) and whole dlo
    detect / dlo track processes, with their wall and CPU times."""
    completed = bench("--tracking", "--quick", "--json")
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    *videos, total = results["frames"]
    assert total["case"] == "all frames" and total["frames"] == 9 * len(videos)
    for row in results["frames"]:
        assert row["frames"] % 9 == 0  # the first of a video's 10 frames starts the tracks
        assert row["track_cpu_p50_ms"] > 0 and 0 < row["detect_p50_ms"] <= row["both_p50_ms"]
    assert [row["command"] for row in results["processes"]] == ["dlo detect", "dlo track"]
    for row in results["processes"]:
        assert row["cpu_s_median"] > 0 and row["fps_whole_process_cpu"] > 0
        assert row["fps_reported"] is not None
