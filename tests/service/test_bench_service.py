"""`dlo bench --service --quick` starts a real server, times every path and reports them.

Only the report's shape is checked, never a speed: the benchmark is the measure.
"""

import json
import subprocess
import sys

import pytest

from service.bench.overhead import Row, _print_table

DLO = [sys.executable, "-c", "from service.cli import main; main()"]
PATHS = {
    "bare detect() on the decoded image",
    "bare decode + detect() of the JPEG",
    "HTTP POST /v1/detect, 1 client",
    "HTTP POST /v1/detect, 4 clients",
    "zenoh dlo/bench/image -> chains",
    "zenoh get dlo/detect",
    "HTTP 503 when every worker and queue slot is busy",
}


@pytest.fixture(scope="module")
def results() -> dict:
    """One quick run of the benchmark (a server, a zenoh session, every path), as JSON."""
    completed = subprocess.run(
        [*DLO, "bench", "--service", "--quick", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    return json.loads(completed.stdout)


def test_every_path_is_timed(results: dict) -> None:
    rows = {row["name"]: row for row in results["rows"]}
    assert set(rows) == PATHS
    for row in rows.values():
        assert row["requests"] > 0 and 0 < row["p50_ms"] <= row["p99_ms"]
        assert row["per_second"] > 0
    for name in ("HTTP POST /v1/detect, 1 client", "zenoh dlo/bench/image -> chains"):
        assert rows[name]["detect_timings_p50_ms"] > 0  # the Detections' own timings
    assert results["targets_ms"] == {"http": 2.0, "zenoh": 3.0}
    refusals = rows["HTTP 503 when every worker and queue slot is busy"]
    assert results["refusal_p99_ms"] == refusals["p99_ms"] and results["refusal_target_ms"] > 0
    bare = rows["bare decode + detect() of the JPEG"]["p50_ms"]
    http = rows["HTTP POST /v1/detect, 1 client"]["p50_ms"]
    assert results["http_overhead_p50_ms"] == http - bare


def test_the_table_shows_every_path_and_the_targets(results: dict, capsys) -> None:
    _print_table(results, [Row(**row) for row in results["rows"]])
    printed = capsys.readouterr().out
    assert "service overhead" in printed
    for name in PATHS:
        assert name in printed
    for path in ("http", "zenoh"):
        assert f"{path}: adds" in printed and "target <=" in printed
    assert "503 when full:" in printed


def test_the_replica_benchmark_reports_both_configurations() -> None:
    """`dlo bench --service --replicas 2`: one replica, then two; the shape, not a speed."""
    completed = subprocess.run(
        [*DLO, "bench", "--service", "--replicas", "2", "--cameras", "2", "--quick", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    results = json.loads(completed.stdout)
    assert [run["replicas"] for run in results["runs"]] == [1, 2]
    assert results["assignment"] == "balanced" and "no CPU" in results["detection"]
    for run in results["runs"]:
        assert run["frames"] > 0 and sum(run["frames_by_replica"]) == run["frames"]
        assert sum(run["cameras_by_replica"]) == 2  # each camera answered by one replica
    assert results["ratio"] == results["runs"][1]["per_second"] / results["runs"][0]["per_second"]


def test_replicas_go_with_service_only() -> None:
    completed = subprocess.run(
        [*DLO, "bench", "--replicas", "3"], capture_output=True, text=True, timeout=60
    )
    assert completed.returncode == 2 and "--replicas applies only with --service" in (
        completed.stderr
    )
