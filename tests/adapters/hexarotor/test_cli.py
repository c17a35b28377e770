"""``dlo hexa trial`` and ``dlo feasibility`` through the real ``dlo`` app."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from adapters.hexarotor.approach import Geofence, plan_approach
from adapters.hexarotor.fake_dynamics import Disturbance
from adapters.hexarotor.trial import (
    TRIAL_APPROACH,
    TrialOutcome,
    TrialTarget,
    format_trial_table,
    run_trials,
    trial_targets,
)
from adapters.hexarotor.wrench import HexarotorGeometry, max_force_along
from service.cli import app
from tests.adapters.builders import grasp_target

runner = CliRunner()


def invoke(*arguments: str):
    result = runner.invoke(app, list(arguments))
    assert "Traceback" not in result.output
    return result


# -- feasibility ---------------------------------------------------------------------------


def test_usb_pull_json_has_exactly_the_three_keys() -> None:
    result = invoke("feasibility", "--pull", "15.84", "--direction", "1", "0", "0", "--json")
    assert result.exit_code == 0, result.output
    answer = json.loads(result.stdout)
    assert set(answer) == {"feasible", "max_force_n", "margin_n"}
    reach = max_force_along(HexarotorGeometry(), (1, 0, 0))
    assert answer["max_force_n"] == pytest.approx(reach, abs=1e-3)
    assert answer["margin_n"] == pytest.approx(reach - 15.84, abs=1e-3)
    assert answer["feasible"] is (reach >= 15.84)


def test_vehicle_options_and_negative_directions_are_understood() -> None:
    result = invoke(
        "feasibility",
        "--mass",
        "2.5",
        "--arm-length",
        "0.25",
        "--tilt-deg",
        "25",
        "--max-thrust",
        "12",
        "--drag-coeff",
        "0.01",
        "--pull",
        "3",
        "--direction",
        "0",
        "-1",
        "0",
        "--json",
    )
    assert result.exit_code == 0, result.output
    geometry = HexarotorGeometry(2.5, 0.25, 25.0, 12.0, 0.01)
    assert json.loads(result.stdout)["max_force_n"] == pytest.approx(
        max_force_along(geometry, (0, -1, 0)), abs=1e-3
    )


def test_text_answer_and_plot(tmp_path: Path) -> None:
    plot = tmp_path / "slice.png"
    result = invoke("feasibility", "--pull", "5", "--direction", "0", "1", "1", "--plot", str(plot))
    assert result.exit_code == 0, result.output
    assert "feasible: yes" in result.stdout
    assert "margin: +" in result.stdout
    image = cv2.imread(str(plot))
    assert image is not None and image.ndim == 3
    assert (image != 255).any()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--pull", "5", "--direction", "0", "0", "0"], "zero vector"),
        (["--pull", "-5", "--direction", "1", "0", "0"], "pull"),
        (["--pull", "5", "--direction", "1", "0", "0", "--tilt-deg", "95"], "tilt_deg"),
        (["--pull", "5", "--direction", "1", "0", "0", "--plot", "out.jpg"], ".png"),
        (["--pull", "5", "--direction", "1", "0"], "direction"),
    ],
)
def test_bad_input_is_a_usage_error_without_traceback(arguments, message) -> None:
    result = invoke("feasibility", *arguments)
    assert result.exit_code == 2
    assert message in result.output


def test_a_vehicle_that_cannot_hover_is_not_feasible() -> None:
    result = invoke("feasibility", "--pull", "1", "--direction", "1", "0", "0", "--mass", "50")
    assert result.exit_code == 0
    assert "feasible: no" in result.stdout
    assert "cannot hold its own weight" in result.stderr


# -- trial ----------------------------------------------------------------------------------


def test_trial_targets_come_from_the_detected_scene_and_fit_the_fence() -> None:
    targets = trial_targets(5, seed=1)
    assert len(targets) == 5
    fence = Geofence()
    for target in targets:
        assert not target.grasp.inferred
        plan = plan_approach(target.target_ned, target.heading_ned, TRIAL_APPROACH)
        for point in (plan.target_ned, plan.standoff_ned, plan.final_ned):
            assert fence.contains(point)
        assert target.target_ned[2] == pytest.approx(-1.0)  # the table top, 1 m up
    assert trial_targets(5, seed=1) == targets  # seeded


def test_summary_and_table() -> None:
    outcome = TrialOutcome(errors_m=[0.004, 0.006, 0.011], failures=[])
    summary = outcome.summary()
    assert summary["closed"] == 3 and summary["failed"] == 0
    assert summary["max_mm"] == pytest.approx(11.0)
    assert summary["mean_mm"] == pytest.approx(7.0)
    assert summary["std_mm"] == pytest.approx(float(np.std([4, 6, 11], ddof=1)))
    table = format_trial_table(summary)
    assert "| 3 | 11.00 | 7.00 |" in table


TWO_TARGETS = [
    TrialTarget(grasp_target(0.0, 0.0, 0.0, yaw=0.0), target_ned=(0.6, 0.0, -0.8), heading_ned=0.0),
    TrialTarget(grasp_target(0.1, 0.2, 0.0, yaw=0.5), target_ned=(0.9, 0.4, -0.9), heading_ned=0.5),
]


@pytest.mark.parametrize("realtime", [False, True], ids=["lockstep", "wall clock"])
def test_one_approach_in_process_reports_the_ground_truth_error(realtime) -> None:
    target = TWO_TARGETS[0]
    seen: list[tuple[int, float | None, str]] = []
    outcome = run_trials(
        [target],
        seed=3,
        disturbance=Disturbance(),
        on_trial=lambda index, _, error, reason: seen.append((index, error, reason)),
        realtime=realtime,
    )
    assert outcome.failures == []
    (error,) = outcome.errors_m
    assert seen == [(0, error, "closed")]
    assert outcome.measured_errors_m[0] <= TRIAL_APPROACH.tolerance_m
    assert 0.0 < error < 0.03
    assert math.isfinite(outcome.summary()["mean_mm"])
    assert outcome.simulated_s > 1.0


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_lockstep_trials_give_the_same_result_for_the_same_seed(autopilot) -> None:
    def fly(seed: int):
        return run_trials(TWO_TARGETS, seed=seed, autopilot=autopilot, disturbance=Disturbance())

    first, second, other = fly(3), fly(3), fly(4)
    assert first.failures == second.failures == other.failures == []
    # Bit for bit: the same simulated time and the same errors, ground truth and measured.
    assert second.simulated_s == first.simulated_s
    assert second.errors_m == first.errors_m
    assert second.measured_errors_m == first.measured_errors_m
    assert other.errors_m != first.errors_m  # the seed drives the gusts and the noise


def test_the_trial_command_prints_the_same_table_twice() -> None:
    arguments = ("hexa", "trial", "--trials", "2", "--seed", "1")
    first, second = invoke(*arguments), invoke(*arguments)
    assert first.exit_code == second.exit_code == 0, first.output
    assert "| 2 |" in first.stdout
    assert second.stdout == first.stdout


def test_trial_rejects_bad_options() -> None:
    assert invoke("hexa", "trial", "--trials", "0").exit_code == 2
    result = invoke("hexa", "trial", "--trials", "1", "--autopilot", "inav")
    assert result.exit_code == 2
    assert "ardupilot or px4" in result.output


@pytest.mark.slow
def test_trial_command_prints_the_table_as_json() -> None:
    result = invoke("hexa", "trial", "--trials", "2", "--seed", "1", "--json", "--autopilot", "px4")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["trials"] == report["closed"] == 2
    assert len(report["errors_mm"]) == 2
    assert report["max_mm"] == pytest.approx(max(report["errors_mm"]), abs=1e-2)
