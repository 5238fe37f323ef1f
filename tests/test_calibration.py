"""Calibration a lab runs once: joint friction and armature identified from a stand-then-trot bag of the
emulated robot, the base CoM offset, the calibration file, the calibrated model (CoM, armature in the
CasADi dynamics) and the low level's friction feed-forward."""

import json
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc import analysis as hl
from wbmpc import cpin
from wbmpc.control.arm_task import ArmReference
from wbmpc.control.low_level import LowLevelController
from wbmpc.estimation.identification import default_joint_groups, identify_joint_friction
from wbmpc.io.logs import RunLog, save_log
from wbmpc.model.base_com import base_com_link, shift_base_com
from wbmpc.model.calibration import Calibration, CalibrationError, JointParameters
from wbmpc.model.friction import JointFriction
from wbmpc.model.robot import load_b1_z1
from wbmpc.sim.hardware import HardwareProfile
from wbmpc.studies import calibrate as cal

STAND, TROT = 2.0, 2.0  # [s]: the standing settles after ~1.2 s; two trot cycles of swing samples
LEGS = ("hip", "thigh", "calf")
ARM = ("joint1", "joint2", "joint3", "joint4")


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def emulated_bag(robot, tmp_path_factory):
    """A stand-then-trot run on the emulated robot (hardware preset, arm held still) recorded as a robot's
    bag at the 500 Hz command rate: ``(bag path, topic map, the run's full log)``."""
    result, _ = hl.record_emulated_run(
        stand=STAND,
        trot=TROT,
        compiled=True,
        delay=0.0125,
        robot=robot,
        arm_reference=ArmReference(amplitude=(0.0, 0.0, 0.0)),
    )
    assert not result.fell
    log = result.run_log()
    path, topic_map = hl.write_robot_bag(log, tmp_path_factory.mktemp("bag") / "stand_trot", robot, factor=1)
    return path, topic_map, log


@pytest.fixture(scope="module")
def identified(emulated_bag, robot):
    path, topic_map, _ = emulated_bag
    return cal.calibrate(path, robot, topic_map=topic_map)


def _urdf_dynamics(robot) -> dict[str, tuple[float, float]]:
    """``{joint: (friction [N m], damping [N m s/rad])}`` of the URDF, which PyBullet applies as well."""
    root = ET.parse(robot.urdf_path).getroot()
    out = {}
    for joint in root.iter("joint"):
        dynamics = joint.find("dynamics")
        if dynamics is not None:
            out[joint.get("name")] = (float(dynamics.get("friction", 0)), float(dynamics.get("damping", 0)))
    return out


def _emulated_truth(robot, summary) -> dict[str, dict[str, float]]:
    """Per joint group the emulated robot's friction (profile + URDF) and the armature the logged torques
    imply. With the PD law in the 2 kHz motor drivers (``joint_pd="drive"``) the drivers hold their torque
    for a plant step while their damping ``k_d`` acts: sampled at 500 Hz, the torques show an armature
    ``k_d h / 2`` lower (module doc of ``wbmpc.estimation.identification``)."""
    profile = HardwareProfile()
    motors = profile.motor_model(robot)
    urdf = _urdf_dynamics(robot)
    kd = {name: summary["low_level"]["kd"] for name in robot.joint_names}
    kd |= dict.fromkeys(robot.arm_joint_names, summary["low_level"]["arm_gains"][1])
    hold = summary["plant_dt_s"] if summary.get("joint_pd") == "drive" else 0.0
    truth = {}
    for group, joints in default_joint_groups(robot).items():
        k = robot.joint_names.index(joints[0])
        friction, damping = urdf.get(joints[0], (0.0, 0.0))
        truth[group] = {
            "coulomb": motors.coulomb[k] + friction,
            "viscous": motors.viscous[k] + damping,
            "armature": motors.armature[k] - kd[joints[0]] * hold / 2,
        }
    return truth


# ----------------------------------------------------------------------------------- the emulated robot
def test_calibration_recovers_the_emulated_robot(identified, emulated_bag, robot):
    _, _, log = emulated_bag
    offset = np.asarray(identified.calibration.base_com_offset)
    np.testing.assert_allclose(offset, HardwareProfile().base_com_offset, atol=0.01)  # within 1 cm
    # The front share of the weight: moment balance of the emulated robot's (shifted) CoM over its feet in
    # the true standing configurations.
    emulated = shift_base_com(robot, HardwareProfile().base_com_offset)
    data = emulated.model.createData()
    shares = []
    for q in np.asarray(log["q"])[hl.standing_mask(log)]:
        com = pin.centerOfMass(emulated.model, data, q)
        pin.framesForwardKinematics(emulated.model, data, q)
        x = [data.oMf[robot.frame_id(f)].translation[0] for f in robot.foot_frames]
        shares.append((com[0] - (x[2] + x[3]) / 2) / ((x[0] + x[1]) / 2 - (x[2] + x[3]) / 2))
    assert identified.calibration.front_force_ratio == pytest.approx(np.mean(shares), abs=0.01)

    truth = _emulated_truth(robot, log.meta["summary"])
    fits = identified.friction.groups
    for group in LEGS:  # the legs swing fast: every parameter identified
        fit = fits[group]
        assert all(fit.identified.values()), (group, fit.reasons)
        assert fit.coulomb == pytest.approx(truth[group]["coulomb"], rel=0.2)
        assert fit.viscous == pytest.approx(truth[group]["viscous"], rel=0.2)
        assert fit.armature == pytest.approx(truth[group]["armature"], rel=0.15)
    # The arm holds still in the heading frame: its joints move only as the base rocks. A joint that moved
    # enough is identified as accurately as a leg; one that did not is reported, not guessed.
    identified_arm = [g for g in ARM if all(fits[g].identified.values())]
    assert identified_arm, {g: fits[g].reasons for g in ARM}
    for group in ARM:
        fit = fits[group]
        if group in identified_arm:
            assert fit.coulomb == pytest.approx(truth[group]["coulomb"], rel=0.2)
            assert fit.viscous == pytest.approx(truth[group]["viscous"], rel=0.2)
            assert fit.armature == pytest.approx(truth[group]["armature"], rel=0.15)
        for parameter, reason in fit.reasons.items():
            assert getattr(fit, parameter) == 0.0
            assert any(words in reason for words in ("samples", "standard error", "negative estimate"))
    written = identified.calibration.joints
    for group, joints in default_joint_groups(robot).items():
        for joint in joints:
            if any(fits[group].identified.values()):
                assert written[joint].coulomb == pytest.approx(fits[group].coulomb, rel=1e-5)
            else:
                assert joint not in written  # nothing identified: the nominal values stay
    print(identified.table())


def test_cli_writes_a_calibration_that_the_loader_applies(emulated_bag, robot, tmp_path, capsys):
    path, _, _ = emulated_bag
    output = tmp_path / "calib" / "b1_z1.yaml"
    assert cal.main([str(path), "--output", str(output), "--robot", "b1_z1"]) == 0
    printed = capsys.readouterr().out
    assert "base CoM offset" in printed and "calf" in printed and f"wrote {output}" in printed
    calibration = Calibration.load(output)
    assert calibration.path == output and calibration.robot == robot.name
    assert calibration.identification["friction"]["groups"]["calf"]["identified"]["armature"] is True
    calibrated = load_b1_z1(calibration=output)
    assert calibrated.calibration == calibration
    k = calibrated.joint_index_v("RL_calf_joint")
    assert calibrated.model.armature[k] == pytest.approx(calibration.joints["RL_calf_joint"].armature)
    assert calibrated.front_force_ratio == pytest.approx(calibration.front_force_ratio)


@pytest.mark.parametrize(
    "arguments, words",
    [
        (["missing_bag_folder", "--output", "c.yaml"], "no bag or log"),
        (["{log}", "--output", "c.txt"], "must end with"),
        (["{log}", "--output", "c.yaml", "--delay", "-1"], "--delay"),
        (["{log}", "--output", "c.yaml", "--friction-velocity", "0"], "--friction-velocity"),
        (["{log}", "--output", "c.yaml", "--robot", "spot"], "--robot"),
        (["{log}", "--output", "c.yaml", "--topic-map", "missing.json"], "--topic-map"),
        (["{log}"], "--output"),
    ],
)
def test_cli_argument_errors_exit_2_before_any_work(arguments, words, tmp_path, monkeypatch, capsys):
    log = tmp_path / "run.npz"
    log.write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cal, "calibrate", lambda *a, **k: pytest.fail("calibrate ran on bad arguments"))
    with pytest.raises(SystemExit) as exit_info:
        cal.main([a.format(log=log) for a in arguments])
    assert exit_info.value.code == 2
    assert words in capsys.readouterr().err


def test_cli_exits_1_on_a_log_without_standing(robot, tmp_path, capsys):
    log = _synthetic_log(robot, seconds=0.5)  # airborne: every foot in swing, nothing stands
    path = save_log(log, tmp_path / "airborne.npz")
    assert cal.main([str(path), "--output", str(tmp_path / "c.yaml")]) == 1
    assert "standing samples" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


# -------------------------------------------------------------------------- identification, synthetic
PARAMETERS = {  # (Coulomb [N m], viscous [N m s/rad], armature [kg m^2]) per default group
    "hip": (0.8, 0.3, 0.03),
    "thigh": (1.2, 0.1, 0.02),
    "calf": (0.5, 0.4, 0.05),
    "joint1": (1.5, 1.0, 0.006),
    "joint2": (2.0, 0.5, 0.004),
    "joint3": (0.7, 0.8, 0.008),
    "joint4": (0.4, 0.2, 0.002),
}


def _synthetic_log(robot, seconds=2.0, delay=0.003, still=(), dt=0.002, v_s=0.05) -> RunLog:
    """A base held in the air, every joint swinging (``still``: not moving), and the torques the motor model
    of :data:`PARAMETERS` needs, logged ``delay`` seconds before they act."""
    groups = default_joint_groups(robot)
    group_of = {j: g for g, joints in groups.items() for j in joints}
    c, b, ia = (np.array([PARAMETERS[group_of[j]][i] for j in robot.joint_names]) for i in range(3))
    model = robot.model
    data = model.createData()
    rng = np.random.default_rng(1)
    omega = rng.uniform(4.0, 9.0, robot.nj)
    phase = rng.uniform(0, 2 * np.pi, robot.nj)
    amplitude = np.where(np.isin(robot.joint_names, still), 0.0, 0.25)

    def state(time):
        arg = omega * time + phase
        q = robot.q_nominal.copy()
        q[2] += 1.0
        q[7:] += amplitude * np.sin(arg)
        v = np.r_[np.zeros(6), amplitude * omega * np.cos(arg)]
        a = np.r_[np.zeros(6), -amplitude * omega**2 * np.sin(arg)]
        return q, v, a

    t = np.arange(round(seconds / dt)) * dt
    q, v, tau = np.zeros((t.size, robot.nq)), np.zeros((t.size, robot.nv)), np.zeros((t.size, robot.nj))
    for k, time in enumerate(t):
        q[k], v[k], _ = state(time)
        qa, va, aa = state(time + delay)  # the torque logged now acts at t + delay
        motor = c * np.tanh(va[6:] / v_s) + b * va[6:] + ia * aa[6:]
        tau[k] = pin.rnea(model, data, qa, va, aa)[6:] + motor
    contact = np.zeros((t.size, robot.n_feet), dtype=bool)
    return RunLog(signals={"t": t, "q": q, "v": v, "tau": tau, "contact": contact})


def test_identification_recovers_a_synthetic_motor_model(robot):
    log = _synthetic_log(robot, still=("joint4",))
    result = identify_joint_friction(log, robot)
    assert result.base == "odometry"  # no IMU columns: the base velocity differentiated (zero here)
    for group, expected in PARAMETERS.items():
        fit = result.groups[group]
        if group == "joint4":  # never moves: nothing to fit, and said so
            assert not any(fit.identified.values()) and "free samples" in fit.reasons["coulomb"]
            continue
        assert all(fit.identified.values()), (group, fit.reasons)
        np.testing.assert_allclose([fit.coulomb, fit.viscous, fit.armature], expected, rtol=0.02)
        assert fit.delay == pytest.approx(0.003, abs=2e-4)
        assert fit.rms_after < 0.05 * fit.rms_before
    # The torques that reach the links are the rigid-body ones: the motor model removed.
    applied = result.applied_torque(log)
    data = robot.model.createData()
    k = 500
    a = np.gradient(log["v"], log["t"], axis=0)[k]
    rigid = pin.rnea(robot.model, data, log["q"][k], log["v"][k], a)[6:]
    moving = [i for i, j in enumerate(robot.joint_names) if j != "joint4"]
    np.testing.assert_allclose(applied[k, moving], rigid[moving], atol=0.05)
    given = identify_joint_friction(log, robot, delay=0.003, window=0.0)
    assert given.groups["calf"].coulomb == pytest.approx(0.5, rel=0.02)
    assert "calf" in result.table() and "joint4" in result.table()
    assert json.dumps(result.summary())  # JSON-ready for the calibration file


def test_identification_rejects_bad_input_before_work(robot):
    log = _synthetic_log(robot, seconds=0.3)
    signals = log.signals
    cases = [
        (RunLog(signals={k: v for k, v in signals.items() if k != "contact"}), {}, "contact"),
        (RunLog(signals={k: v for k, v in signals.items() if k != "tau"}), {}, "'tau'"),
        (RunLog(signals=signals | {"t": signals["t"] ** 1.5}), {}, "evenly spaced"),
        (RunLog(signals=signals | {"tau": signals["tau"][:, :3]}), {}, "'tau' has shape"),
        (log, {"base": "imu"}, "imu_accelerometer"),
        (log, {"base": "truth"}, "base must be"),
        (log, {"friction_velocity": 0.0}, "friction_velocity"),
        (log, {"delay_range": (0.01, 0.0)}, "delay_range"),
        (log, {"groups": {"hip": ["FL_hip"]}}, "unknown joint 'FL_hip'"),
        (log, {"groups": {"a": ["joint1"], "b": ["joint1"]}}, "is in groups 'a' and 'b'"),
        (RunLog(signals={k: v[:20] for k, v in signals.items()}), {}, "too short"),
    ]
    for bad_log, options, words in cases:
        with pytest.raises(ValueError, match=words):
            identify_joint_friction(bad_log, robot, **options)


# ----------------------------------------------------------------------------------- calibration files
def _calibration() -> Calibration:
    return Calibration(
        base_com_offset=(-0.19, 0.002, 0.0),
        front_force_ratio=0.39,
        friction_velocity=0.05,
        joints={
            "FL_calf_joint": JointParameters(1.0, 0.2, 0.04),
            "joint2": JointParameters(2.3, 2.1, 0.005),
        },
        robot="Unitree B1 + Z1",
        identification={"note": "hand-made", "rms": [0.1, float("nan")]},
    )


@pytest.mark.parametrize("suffix", [".yaml", ".yml", ".json"])
def test_calibration_file_round_trip(suffix, tmp_path):
    calibration = _calibration()
    path = calibration.save(tmp_path / f"calib{suffix}")
    assert calibration.path == path
    loaded = Calibration.load(path)
    assert loaded.joints == calibration.joints and loaded.base_com_offset == calibration.base_com_offset
    assert (loaded.front_force_ratio, loaded.friction_velocity) == (0.39, 0.05)
    assert loaded.identification["rms"] == [0.1, None]  # NaN is written as null (JSON has no NaN)
    text = path.read_text()
    assert "format_version" in text and "coulomb_nm" in text and "armature_kgm2" in text
    if suffix != ".json":
        assert text.startswith("# wbmpc robot calibration") and "[N m s/rad]" in text


def test_bad_calibration_files_name_the_file_and_the_field(tmp_path, robot):
    with pytest.raises(FileNotFoundError, match="no calibration file"):
        Calibration.load(tmp_path / "missing.yaml")
    good = _calibration().to_dict()

    def write(data, name="bad.yaml"):
        path = tmp_path / name
        path.write_text(json.dumps(data) if isinstance(data, dict) else data)
        return path

    cases = [
        ("format_version: 1\njoints: [unclosed\n", "not valid YAML"),
        (good | {"base_com_offset_m": "backwards"}, "'base_com_offset_m' must be 3 numbers"),
        (good | {"base_com_offset_m": [-0.19, "x", 0.0]}, r"base_com_offset_m\[1\]' must be a number"),
        (good | {"front_force_ratio": 1.5}, "'front_force_ratio' must be in"),
        (good | {"friction_velocity_radps": -1}, "friction_velocity_radps"),
        (good | {"format_version": 99}, "newer than this wbmpc reads"),
        (good | {"colour": "red"}, r"unknown fields \['colour'\]"),
        ({k: v for k, v in good.items() if k != "joints"}, "field 'joints' is missing"),
        (
            good
            | {"joints": {"joint2": {"coulomb_nm": "high", "viscous_nms_per_rad": 1, "armature_kgm2": 0}}},
            "'joints.joint2.coulomb_nm' must be a number",
        ),
        (
            good | {"joints": {"joint2": {"coulomb_nm": 1.0, "viscous_nms_per_rad": 1.0}}},
            "'joints.joint2.armature_kgm2' is missing",
        ),
        (
            good | {"joints": {"joint2": {"coulomb_nm": -1, "viscous_nms_per_rad": 1, "armature_kgm2": 0}}},
            "must be >= 0",
        ),
    ]
    for data, words in cases:
        path = write(data)
        with pytest.raises(CalibrationError, match=words) as error:
            Calibration.load(path)
        assert str(path) in str(error.value)
    other = write(good | {"joints": {"elbow_joint": good["joints"]["joint2"]}}, "other_robot.json")
    with pytest.raises(
        CalibrationError, match=r"other_robot.json: field 'joints' names joints \['elbow_joint'\]"
    ):
        load_b1_z1(calibration=other)
    with pytest.raises(CalibrationError, match="calib.txt: a calibration file ends with one of"):
        _calibration().save(tmp_path / "calib.txt")
    with pytest.raises(CalibrationError, match="front_force_ratio"):
        Calibration(front_force_ratio=0.0)


def test_load_robot_with_calibration_moves_the_com_and_sets_the_armature(robot, tmp_path):
    calibration = _calibration()
    calibrated = load_b1_z1(calibration=calibration)
    assert calibrated.calibration is calibration and robot.calibration is None
    assert calibrated.mass == pytest.approx(robot.mass)
    assert calibrated.front_force_ratio == 0.39 and robot.front_force_ratio == 0.5
    # The base body's CoM moves by the link's share of the offset: m_link / m_body * offset.
    _, m_link = base_com_link(robot)
    body, nominal = calibrated.model.inertias[1], robot.model.inertias[1]
    np.testing.assert_allclose(
        body.lever - nominal.lever, m_link / nominal.mass * np.array(calibration.base_com_offset), atol=1e-12
    )
    # The same model as wbmpc.model.base_com.shift_base_com.
    reference = shift_base_com(robot, calibration.base_com_offset, 0.39).model.inertias[1]
    np.testing.assert_allclose(body.toDynamicParameters(), reference.toDynamicParameters(), atol=1e-12)
    armature = np.zeros(robot.nv)
    armature[robot.joint_index_v("FL_calf_joint")] = 0.04
    armature[robot.joint_index_v("joint2")] = 0.005
    np.testing.assert_array_equal(calibrated.model.armature, armature)
    assert not robot.model.armature.any()  # the nominal model is untouched
    friction = calibration.joint_friction(robot)
    assert friction.coulomb[robot.joint_names.index("joint2")] == 2.3
    assert friction.coulomb.sum() == pytest.approx(3.3) and friction.velocity == 0.05
    # From a file, the same robot.
    from_file = load_b1_z1(calibration=calibration.save(tmp_path / "c.yaml"))
    np.testing.assert_array_equal(from_file.model.armature, armature)
    np.testing.assert_allclose(
        from_file.model.inertias[1].toDynamicParameters(), body.toDynamicParameters(), atol=1e-15
    )


def test_casadi_dynamics_include_the_armature(robot):
    model = robot.model.copy()
    rng = np.random.default_rng(3)
    model.armature = rng.uniform(0.005, 0.05, model.nv)  # base entries too, as Pinocchio allows
    smodel = cpin.SymbolicModel(model)
    data = model.createData()
    q = robot.q_nominal.copy()
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3)).coeffs()
    q[7:] += rng.normal(0.0, 0.2, robot.nj)
    v, a, tau = rng.normal(size=model.nv), rng.normal(size=model.nv), 5 * rng.normal(size=model.nv)
    none = ca.DM.zeros(0)
    expected = pin.rnea(model, data, q, v, a)
    assert np.abs(expected - pin.rnea(robot.model, robot.model.createData(), q, v, a)).max() > 0.01
    np.testing.assert_allclose(
        np.array(cpin.rnea_function(smodel, [])(q, v, a, none)).ravel(), expected, atol=1e-10
    )
    qs = ca.SX.sym("q", model.nq)
    M = np.array(ca.Function("M", [qs], [cpin.crba(smodel, qs)])(q))
    upper = pin.crba(model, data, q)
    np.testing.assert_allclose(M, np.triu(upper) + np.triu(upper, 1).T, atol=1e-10)
    for method in ("articulated", "crba"):
        ddq = np.array(cpin.aba_function(smodel, [], method=method)(q, v, tau, none)).ravel()
        np.testing.assert_allclose(ddq, pin.aba(model, data, q, v, tau), atol=1e-9)


# ----------------------------------------------------------------------------------------- low level
def _plan(nj=2):
    dts = np.array([0.01, 0.02])
    return SimpleNamespace(
        dts=dts,
        node_times=np.r_[0.0, np.cumsum(dts)],
        tau=np.array([[0.0] * nj, [10.0] * nj]),
        q=np.zeros((3, 7 + nj)),
        v=np.tile(np.r_[np.zeros(6), np.linspace(-0.04, 2.0, nj)], (3, 1)),
        a=np.zeros((2, 6 + nj)),
    )


def test_low_level_friction_feedforward_on_the_desired_rate():
    q, v = np.zeros(9), np.r_[np.zeros(6), 0.5, -0.5]  # measured rates differ from the desired ones
    plain = LowLevelController(kp=10.0, kd=2.0)
    plain.update(_plan())
    ref = plain.reference(0.005)
    tau_plain = plain.torque(0.005, q, v)
    np.testing.assert_allclose(tau_plain, ref.tau_ff + 10.0 * (ref.q_des - q[7:]) + 2.0 * (ref.v_des - v[6:]))
    friction = JointFriction([1.0, 0.5], [0.2, 0.1], velocity=0.05)
    compensated = LowLevelController(kp=10.0, kd=2.0, friction=friction)
    compensated.update(_plan())
    extra = compensated.torque(0.005, q, v) - tau_plain
    np.testing.assert_allclose(extra, [1.0, 0.5] * np.tanh(ref.v_des / 0.05) + [0.2, 0.1] * ref.v_des)
    assert extra[0] < 0 < extra[1]  # the desired rates' signs (the measured ones are the opposite)
    # The feed-forward a motor drive would receive carries it too, and says which part it is.
    sent = compensated.last_reference
    np.testing.assert_allclose(sent.tau_ff - ref.tau_ff, extra)
    np.testing.assert_allclose(sent.tau_friction, extra)
    assert ref.tau_friction is None
    clipped = LowLevelController(torque_limits=np.array([5.0, 5.0]), friction=friction)
    clipped.update(_plan())
    assert np.all(np.abs(clipped.torque(0.01, q, v)) <= 5.0) and clipped.violations == 1
    with pytest.raises(ValueError, match="friction feed-forward 2 joints"):
        compensated.update(_plan(nj=3))
    with pytest.raises(ValueError, match="friction must be a JointFriction"):
        LowLevelController(friction={"coulomb": 1.0})


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"coulomb": [1.0, -1.0], "viscous": [0.0, 0.0]}, "coulomb"),
        ({"coulomb": [1.0], "viscous": [0.0, 0.0]}, "one value per joint"),
        ({"coulomb": [1.0], "viscous": [np.nan]}, "viscous"),
        ({"coulomb": [1.0], "viscous": [0.0], "velocity": 0.0}, "velocity"),
    ],
)
def test_joint_friction_rejects_bad_values(kwargs, words):
    with pytest.raises(ValueError, match=words):
        JointFriction(**kwargs)
