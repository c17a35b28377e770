"""`dlo bench --quick` runs end to end, on one thread, and reports every table."""

import json
import subprocess
import sys

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
    for case in results["cases"] + results["scaling_area"] + results["scaling_cables"]:
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
    assert results["peak_rss_mb"] > 0


def test_dlo_bench_prints_tables_by_default(tmp_path):
    completed = subprocess.run(
        [*DLO, "bench", "--quick", "--dataset", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    for heading in ("one thread", "after warm-up", "p50 per stage", "scaling with image area"):
        assert heading in completed.stdout
    assert "peak resident memory" in completed.stdout
