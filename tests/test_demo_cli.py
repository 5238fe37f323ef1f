"""The demo command line: bad arguments are refused before any work with a one-line reason; a fall or a
failed run exits non-zero; a gait schedule runs end to end."""

import json

import pytest

from wbmpc.studies import demo


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--nodes", "0"], "--nodes must be"),
        (["--nodes", "2"], "--nodes must be >= 3"),
        (["--duration", "0"], "--duration must be"),
        (["--duration", "-1"], "--duration must be"),
        (["--duration", "nan"], "--duration must be"),
        (["--period", "0"], "--period must be"),
        (["--kp", "-1"], "--kp must be"),
        (["--kd", "inf"], "--kd must be"),
        (["--speed", "inf"], "--speed must be finite"),
        (["--speed", "1e6"], "--speed: base speed 1e+06 m/s is beyond the physical limit of 10 m/s"),
        (["--speed", "-30"], "--speed: base speed 30 m/s is beyond the physical limit"),
        (["--gait", "stand:1,trot@1e6:2"], "segment 1 (trot@1e+06): base speed 1e+06 m/s is beyond"),
        (["--gait", "gallop"], "unknown gait"),
        (["--gait", "stand:2,trot"], "needs a duration"),
        (["--gait", "trot", "--period", "0.80025"], "not a multiple of the schedule tick"),
        (["--robot", "spot"], "unknown robot"),
        (["--output", "/proc/not-a-folder"], "not a writable folder"),
    ],
)
def test_bad_arguments_exit_2_with_the_reason(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        demo.main([*argv, "--quiet", "--no-replay"])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_exit_status_reports_a_fall_and_poor_convergence(capsys):
    assert demo.exit_status({"fell": False, "converged_fraction": 1.0, "duration_s": 1.0}) == 0
    assert demo.exit_status({"fell": True, "converged_fraction": 1.0, "duration_s": 0.71}) == 1
    assert "fell at t = 0.71 s" in capsys.readouterr().err
    assert demo.exit_status({"fell": False, "converged_fraction": 0.5, "duration_s": 1.0}) == 1
    assert "50 % of the solves converged" in capsys.readouterr().err


def test_a_gait_schedule_and_the_robot_without_arm_run_end_to_end(tmp_path):
    """``--robot b1`` used to fail at the end (the torque plot asked for the arm's joint2)."""
    summary = demo.main(
        [
            "--robot", "b1", "--gait", "stand:0.1,trot:0.3", "--nodes", "6", "--duration", "0.3",
            "--quiet", "--no-replay", "--output", str(tmp_path),
        ]
    )  # fmt: skip
    assert summary["gait"] == "stand:0.1+trot:0.3" and not summary["fell"]
    assert json.loads((tmp_path / "summary.json").read_text())["robot"] == summary["robot"]
    assert (tmp_path / "torques.png").stat().st_size > 0
    assert demo.exit_status(summary) == 0
