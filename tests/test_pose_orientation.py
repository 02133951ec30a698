"""Measured marker orientations in pose campaigns (issue 29, item 1: "optionally orientations"):
the stacked Jacobian against central differences, the columns read and written in their unit,
the fit with orientations weighted by sigma_t / sigma_r recovering the hidden parameters and
reaching both noises, validate's rotation keys, and the import of a rig's rotation columns.
"""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pinocchio as pin
import pytest
from pose_truth import add_intervals
from stats import Coverage

from stiffness.calibration.pose_campaign import load_pose_campaign, write_pose_campaign
from stiffness.calibration.pose_fit import fit_pose_model, rows_of, starting_frame
from stiffness.calibration.pose_model import Marker, PoseModel
from stiffness.calibration.pose_model_file import write_pose_model
from stiffness.calibration.pose_orientation import PoseObservations
from stiffness.cli.main import main
from stiffness.errors import DataFileWarning, StiffnessError
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.robot.calibration import read_pose_calibration
from stiffness.robot.robot import load_robot
from stiffness.units import Units

NOISE = 20e-6       # m
NOISE_ROT = 1e-4    # rad (about 20 arc seconds)
PAYLOAD = np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0])
MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
           Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]
FAMILIES = ("frame", "markers", "joint_offsets", "geometry", "joint_compliance")


@pytest.fixture(scope="module")
def ur10():
    return load_robot("ur10", frame="tool0")


def _hidden(rng: np.random.Generator) -> HiddenPoseErrors:
    eps = np.zeros((6, 6))
    eps[:, :2] = rng.normal(0.0, 4e-4, (6, 2))
    return HiddenPoseErrors(pin.exp3(rng.normal(size=3)), rng.uniform(-2, 2, 3),
                            np.array([m.offset for m in MARKERS]) + rng.normal(0, 2e-3, (2, 3)),
                            rng.normal(0.0, 1e-3, 6), eps,
                            stiffness=np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]))


def _campaign(robot, seed: int, n: int = 40, **kw):
    rng = np.random.default_rng(seed)
    hidden = _hidden(rng)
    return hidden, simulate_pose_campaign(robot, MARKERS, hidden, n, NOISE, seed=seed,
                                          payload=PAYLOAD, rotation_noise_std=NOISE_ROT, **kw)


def test_stacked_jacobian_by_central_differences(ur10):
    """Positions and weighted orientation errors, every family's column (geometry included),
    against central differences at zero compliance (where every column is exact): to 1e-6;
    an unseen orientation is left out of the stack."""
    _, c = _campaign(ur10, 0, n=3)
    c.rotations[1, 0] = np.nan
    model = PoseModel(ur10, c.markers, FAMILIES, starting_frame(c), c.loads)
    obs = PoseObservations(model, c, rows_of(model, c))
    rng = np.random.default_rng(1)
    scales = np.array([p.scale for p in model.parameters])
    x = rng.normal(size=model.size) * scales * 3
    x[model.slices()["joint_compliance"]] = 0.0
    r, jac = obs.evaluate(x)
    assert r.size == obs.size == 3 * 6 + 3 * 5
    for col in range(model.size):
        e = np.zeros(model.size)
        e[col] = 1e-2 * scales[col]
        fd = (obs.evaluate(x + e, False)[0] - obs.evaluate(x - e, False)[0]) / (2 * e[col])
        assert np.abs(jac[:, col] - fd).max() <= 1e-6 * max(np.abs(fd).max(), 1e-3), \
            model.parameters[col].label


def test_orientations_written_and_read_in_their_unit(ur10, tmp_path):
    """A campaign with orientations in deg (rotation unit) and mm: read back to 1e-12, its
    rotation noise too; partial rotation columns and a rotation noise without them are
    refused in one line naming the fix."""
    _, c = _campaign(ur10, 2, n=6)
    c.units = Units("deg", "N", "mm", rotation_unit="deg")
    c.rotations[2, 1] = np.nan
    write_pose_campaign(c, tmp_path / "a")
    back = load_pose_campaign(tmp_path / "a")
    assert np.allclose(back.rotations, c.rotations, rtol=0, atol=1e-12, equal_nan=True)
    assert back.noise_std_rotation == pytest.approx(NOISE_ROT, rel=1e-12)
    toml_a = tmp_path / "a" / "campaign.toml"  # the deflection campaigns' spelling is written
    toml_a.write_text(toml_a.read_text().replace("rotation_noise_std", "noise_std_rotation"))
    assert load_pose_campaign(tmp_path / "a").noise_std_rotation == pytest.approx(
        NOISE_ROT, rel=1e-12)
    csv = (tmp_path / "a" / "measurements.csv").read_text()
    assert "tip_rx,tip_ry,tip_rz" in csv.splitlines()[0]
    lines = csv.splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h != "elbow_rz"]
    (tmp_path / "a" / "measurements.csv").write_text(
        "\n".join(",".join(row.split(",")[i] for i in keep) for row in lines) + "\n")
    with pytest.raises(StiffnessError, match="all\nthree rotation|all three rotation"):
        load_pose_campaign(tmp_path / "a")
    c.rotations = None
    write_pose_campaign(c, tmp_path / "b")
    toml = (tmp_path / "b" / "campaign.toml").read_text()
    (tmp_path / "b" / "campaign.toml").write_text(
        toml.replace('data = "measurements.csv"', 'data = "measurements.csv"\n'
                     "noise_std_rotation = 0.01"))
    with pytest.raises(StiffnessError, match="no marker has"):
        load_pose_campaign(tmp_path / "b")


def test_fit_with_orientations_recovers_the_truth(ur10):
    """5 seeds, 40 poses, 20 um and 1e-4 rad: every fitted parameter's 95 % interval covers
    the truth at a consistent rate and spread (:meth:`stats.Coverage.check`), the orientation
    residual is
    the rotation noise (RMS within 15 %), and the orientations narrow the intervals
    (median interval ratio to a positions-only fit of the same poses below 0.95). Measured
    on seeds 0-3: median ratios 0.80, 0.82, 0.85, 0.85; every fitted parameter of seeds 0-4:
    178 of 180 covered, standardised variance 0.84."""
    cov = Coverage()
    narrower = []
    for seed in range(5):
        hidden, c = _campaign(ur10, seed)
        model = PoseModel(ur10, c.markers, FAMILIES, starting_frame(c), c.loads)
        fit = fit_pose_model(model, c, rows_of(model, c), list(FAMILIES))
        rot = fit.rotation_residual[np.isfinite(fit.rotation_residual)]
        assert np.sqrt(np.mean(rot ** 2)) == pytest.approx(NOISE_ROT, rel=0.15)
        add_intervals(cov, fit, hidden, c)
        c.rotations, c.noise_std_rotation = None, None
        plain = fit_pose_model(model, c, rows_of(model, c), list(FAMILIES))
        both = [i for i in plain.identifiability.kept if i in fit.identifiability.kept]
        narrower.append(np.median(fit.std()[both] / plain.std()[both]))
    cov.check()
    assert max(narrower) < 0.95, narrower


def test_validate_reports_rotation_errors(ur10, tmp_path, capsys):
    """A fitted model file, then validate --json on another campaign with orientations: the position
    keys as before, and rotation_rms / _mean_error / _max_error / rotation_unit overall and per
    marker, the RMS angle that of the noise (sqrt(3) sigma_r, in the campaign's unit)."""
    rng = np.random.default_rng(5)
    hidden = _hidden(rng)
    hidden.stiffness = None
    for name, seed in (("a", 5), ("b", 6)):
        c = simulate_pose_campaign(ur10, MARKERS, hidden, 30, NOISE, seed=seed,
                                   rotation_noise_std=NOISE_ROT,
                                   units=Units("rad", "N", "mm", rotation_unit="deg"))
        write_pose_campaign(c, tmp_path / name)
    a = load_pose_campaign(tmp_path / "a")
    fams = ["frame", "markers", "joint_offsets", "geometry"]
    model = PoseModel(ur10, a.markers, tuple(fams), starting_frame(a), a.loads)
    write_pose_model(fit_pose_model(model, a, rows_of(model, a), fams), a,
                     tmp_path / "model.json")
    assert main(["validate", str(tmp_path / "model.json"), str(tmp_path / "b"), "--json"]) == 0
    val = json.loads(capsys.readouterr().out)
    assert {"rms", "mean_error", "max_error", "unit", "rows", "markers"} <= set(val)
    assert val["unit"] == "mm" and val["rotation_unit"] == "deg"
    expected = np.rad2deg(np.sqrt(3) * NOISE_ROT)
    assert val["rotation_rms"] == pytest.approx(expected, rel=0.25)
    for marker in val["markers"].values():
        assert {"rms", "rotation_rms", "rotation_mean_error", "rotation_max_error",
                "rotation_unit"} <= set(marker)


def test_import_maps_rotation_columns(ur10, tmp_path, capsys):
    """campaign import --kind poses with <marker>_rx.. mapped from a tracker's columns (deg,
    a marker's orientation unseen on a row) and --noise-rotation: the same orientations
    (1e-12 relative) and rotation noise."""
    _, c = _campaign(ur10, 13, n=8)
    c.rotations[3, 0] = np.nan
    q_deg = np.rad2deg(c.q)
    joints = ["id,j1,j2,j3,j4,j5,j6"] + [",".join([f"k{i}"] + [repr(float(v)) for v in q])
                                         for i, q in enumerate(q_deg)]
    cols = ["T_x", "T_y", "T_z", "E_x", "E_y", "E_z", "T_a", "T_b", "T_c", "E_a", "E_b", "E_c"]
    tracker = ["id," + ",".join(cols)]
    for i in range(c.n_rows):
        values = np.r_[c.positions[i].ravel() * 1e3, np.rad2deg(c.rotations[i]).ravel()]
        tracker.append(",".join([f"k{i}"] + ["" if not np.isfinite(v) else repr(float(v))
                                             for v in values]))
    (tmp_path / "joints.csv").write_text("\n".join(joints) + "\n")
    (tmp_path / "tracker.csv").write_text("\n".join(tracker) + "\n")
    mapping = ",".join([f"q{i}=j{i}" for i in range(1, 7)]
                       + [f"tip_{a}=T_{a}" for a in "xyz"] + [f"elbow_{a}=E_{a}" for a in "xyz"]
                       + [f"tip_r{a}=T_{b}" for a, b in zip("xyz", "abc", strict=True)]
                       + [f"elbow_r{a}=E_{b}" for a, b in zip("xyz", "abc", strict=True)])
    assert main(["campaign", "import", str(tmp_path / "joints.csv"), str(tmp_path / "tracker.csv"),
                 "--kind", "poses", "--robot", "ur10", "--frame", "tool0", "--join", "id",
                 "--map", mapping, "--units", "angle=deg,length=mm",
                 "--marker", "tip=tool0@0,30,50", "--marker", "elbow=forearm_link@0,50,200",
                 "--noise", "0.02", "--noise-rotation", str(np.rad2deg(NOISE_ROT)),
                 "--out", str(tmp_path / "campaign")]) == 0
    capsys.readouterr()
    back = load_pose_campaign(tmp_path / "campaign")
    assert np.allclose(back.rotations, c.rotations, rtol=1e-12, atol=1e-15, equal_nan=True)
    assert back.noise_std_rotation == pytest.approx(NOISE_ROT, rel=1e-12)


def test_a_probe_mounted_turned_is_declared_and_its_orientations_explained(ur10, tmp_path,
                                                                            capsys):
    """FIGAROH's UR10 data: a 6-D probe whose axes are wrist_3_link's turned by 29.5 deg about
    x. Its orientations leave the nominal model 200 noise std off; declared
    (`--marker NAME=FRAME@X,Y,Z@RX,RY,RZ`, `[markers] rotation`),
    the simulated probe (the simulator turns the frame's rotation matrix, not the fit's axis
    points) is explained to its noise, through the campaign and model files and validate."""
    mount = np.array([-0.5145, -0.0165, -0.013])  # rad: FIGAROH's UR10 probe, estimated
    markers = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05]), pin.exp3(mount))]
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([1.0, -0.5, 0.3]),
                              np.array([[0.001, 0.031, 0.049]]), np.zeros(6), np.zeros((6, 6)))
    c = simulate_pose_campaign(ur10, markers, hidden, 10, NOISE, seed=3,
                               rotation_noise_std=NOISE_ROT)
    q_deg = np.rad2deg(c.q)
    rows = ["j1,j2,j3,j4,j5,j6,X,Y,Z,A,B,C"] + [
        ",".join(repr(float(v)) for v in np.r_[q_deg[i], c.positions[i, 0] * 1e3,
                                               np.rad2deg(c.rotations[i, 0])])
        for i in range(c.n_rows)]
    (tmp_path / "rig.csv").write_text("\n".join(rows) + "\n")
    argv = ["campaign", "import", str(tmp_path / "rig.csv"), "--kind", "poses", "--robot",
            "ur10", "--frame", "tool0", "--map", ",".join(
                [f"q{i}=j{i}" for i in range(1, 7)] + ["tip_x=X,tip_y=Y,tip_z=Z",
                                                       "tip_rx=A,tip_ry=B,tip_rz=C"]),
            "--units", "angle=deg,length=mm", "--noise", "0.02",
            "--noise-rotation", str(np.rad2deg(NOISE_ROT)), "--quiet"]
    turned = ",".join(repr(float(v)) for v in np.rad2deg(mount))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*argv, "--marker", f"tip=tool0@0,30,50@{turned}",
                     "--out", str(tmp_path / "declared")]) == 0
    assert not [w for w in caught if "mounted turned" in str(w.message)]
    # undeclared, the import estimates the mounting (the orientations alone: the measuring
    # frame's rotation and the mounting in turn) and says what to declare, in deg
    with pytest.warns(DataFileWarning, match="a 6-D probe mounted turned") as said:
        assert main([*argv, "--marker", "tip=tool0@0,30,50", "--out", str(tmp_path / "not")
                     ]) == 0
    message = next(str(w.message) for w in said if "mounted turned" in str(w.message))
    declare = re.search(r"rotation = \[([^\]]+)\] \(deg;", message)
    assert declare, message
    estimate = np.deg2rad([float(v) for v in declare.group(1).split(",")])
    assert np.degrees(np.linalg.norm(pin.log3(pin.exp3(estimate).T @ pin.exp3(mount)))) < 0.02
    capsys.readouterr()
    back = load_pose_campaign(tmp_path / "declared")
    np.testing.assert_allclose(back.markers[0].rotation, pin.exp3(mount), rtol=0, atol=1e-12)
    fams = ["frame", "markers"]
    rms = {}
    for name in ("declared", "not"):
        a = load_pose_campaign(tmp_path / name)
        model = PoseModel(ur10, a.markers, tuple(fams), starting_frame(a), a.loads)
        write_pose_model(fit_pose_model(model, a, rows_of(model, a), fams), a,
                         tmp_path / f"{name}.json")
        assert main(["validate", str(tmp_path / f"{name}.json"), str(tmp_path / "declared"),
                     "--json"]) == 0
        rms[name] = json.loads(capsys.readouterr().out)["rotation_rms"]
    assert rms["declared"] == pytest.approx(np.rad2deg(np.sqrt(3) * NOISE_ROT), rel=0.35)
    # undeclared, the markers family's mounting turn takes the whole 29.5 deg (beyond its
    # physical few degrees, hence the warning): the model file's calibrated axes are the
    # probe's, and validate explains the orientations with them
    cal = read_pose_calibration(tmp_path / "not.json")
    assert np.degrees(np.linalg.norm(pin.log3(cal.marker_rotation("tip").T @ pin.exp3(mount)))
                      ) < 0.02
    assert rms["not"] == pytest.approx(rms["declared"], rel=0.05)


def test_import_reads_roll_pitch_yaw_columns(ur10, tmp_path, capsys):
    """FIGAROH's and ROS's rigs write orientations as roll, pitch, yaw (R = Rz Ry Rx), not
    rotation vectors: --rotation-format rpy turns them into the campaign's rotation vectors
    (those simulated, to 1e-12; the matrices built with Pinocchio's rpy, apart from the
    import's route); refused for a deflection campaign."""
    _, c = _campaign(ur10, 17, n=6)
    c.rotations[2, 1] = np.nan
    rpy = np.array([[np.full(3, np.nan) if not np.all(np.isfinite(r)) else
                     np.rad2deg(pin.rpy.matrixToRpy(pin.exp3(r))) for r in row]
                    for row in c.rotations])
    cols = [f"{m}_{a}" for m in ("tip", "elbow") for a in "xyz"] + [
        f"{m}_r{a}" for m in ("tip", "elbow") for a in "xyz"]
    rows = [",".join([f"q{i}" for i in range(1, 7)] + cols)] + [
        ",".join("" if not np.isfinite(v) else repr(float(v)) for v in np.r_[
            np.rad2deg(c.q[i]), c.positions[i].ravel() * 1e3, rpy[i].ravel()])
        for i in range(c.n_rows)]
    (tmp_path / "rig.csv").write_text("\n".join(rows) + "\n")
    argv = ["campaign", "import", str(tmp_path / "rig.csv"), "--robot", "ur10", "--frame",
            "tool0", "--units", "angle=deg,length=mm", "--quiet", "--rotation-format", "rpy"]
    assert main([*argv, "--kind", "poses", "--marker", "tip=tool0@0,30,50", "--marker",
                 "elbow=forearm_link@0,50,200", "--out", str(tmp_path / "c")]) == 0
    back = load_pose_campaign(tmp_path / "c")
    np.testing.assert_allclose(back.rotations, c.rotations, rtol=0, atol=1e-12)
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "d")]) == 2
    assert "--rotation-format is for --kind poses" in capsys.readouterr().err


def test_import_reads_quaternion_columns(ur10, tmp_path, capsys):
    """A tracker's rigid body written as quaternions (FIGAROH's TIAGo exp_data_0924.csv:
    trans_x..z, rot_x, rot_y, rot_z, rot_w) had no rotation format: --rotation-format
    quaternion reads ``<marker>_qx, _qy, _qz, _qw`` (scalar last) into the campaign's rotation
    vectors (those simulated, to 1e-9; the quaternions built with Pinocchio, sign flipped on
    odd rows: q and -q are one rotation). A row off unit norm by more than 1 % (that file's
    line 3: 1.0324) is warned about naming its line and read normalised; one off by more than
    half is refused (not a quaternion)."""
    _, c = _campaign(ur10, 17, n=6)
    c.rotations[2, 1] = np.nan
    quats = np.full(c.rotations.shape[:2] + (4,), np.nan)
    for index in np.ndindex(c.rotations.shape[:2]):
        if np.all(np.isfinite(c.rotations[index])):
            quats[index] = pin.Quaternion(pin.exp3(c.rotations[index])).coeffs() * (
                -1.0 if index[0] % 2 else 1.0)
    quats[4, 0] *= 1.03
    cols = [f"{m}_{a}" for m in ("tip", "elbow") for a in "xyz"] + [
        f"{m}_q{a}" for m in ("tip", "elbow") for a in "xyzw"]

    def write(q: np.ndarray) -> None:
        rows = [",".join([f"q{i}" for i in range(1, 7)] + cols)] + [
            ",".join("" if not np.isfinite(v) else repr(float(v)) for v in np.r_[
                np.rad2deg(c.q[i]), c.positions[i].ravel() * 1e3, q[i].ravel()])
            for i in range(c.n_rows)]
        (tmp_path / "rig.csv").write_text("\n".join(rows) + "\n")

    write(quats)
    argv = ["campaign", "import", str(tmp_path / "rig.csv"), "--robot", "ur10", "--frame",
            "tool0", "--units", "angle=deg,length=mm", "--quiet", "--kind", "poses",
            "--rotation-format", "quaternion", "--marker", "tip=tool0@0,30,50", "--marker",
            "elbow=forearm_link@0,50,200"]
    with pytest.warns(DataFileWarning, match=r"1 of 6 rows hold quaternions off unit norm by "
                      r"more than 0.01 \(first: line 6, .* has norm 1.03\); read normalised: "
                      r"check line 6"):
        assert main([*argv, "--out", str(tmp_path / "c")]) == 0
    back = load_pose_campaign(tmp_path / "c")
    np.testing.assert_allclose(back.rotations, c.rotations, rtol=0, atol=1e-9)
    quats[1, 1] *= 3.0
    write(quats)
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "d")]) == 2
    assert "line 3" in (err := capsys.readouterr().err) and "not a quaternion" in err, err


def test_refused_quaternion_quotes_its_own_row(ur10, tmp_path, capsys):
    """A marker with a row off unit norm by a few percent (warned) before one off by 3x
    (refused): the refusal quotes the refused row's four values with their own norm, 3 (the
    values were the warned row's, norm 1.03, beside the other row's norm)."""
    _, c = _campaign(ur10, 17, n=6)
    quats = np.array([[pin.Quaternion(pin.exp3(r)).coeffs() for r in row]
                      for row in c.rotations])
    quats[1, 0] *= 1.03
    quats[3, 0] *= 3.0
    cols = [f"{m}_{a}" for m in ("tip", "elbow") for a in "xyz"] + [
        f"{m}_q{a}" for m in ("tip", "elbow") for a in "xyzw"]
    rows = [",".join([f"q{i}" for i in range(1, 7)] + cols)] + [
        ",".join(repr(float(v)) for v in np.r_[
            np.rad2deg(c.q[i]), c.positions[i].ravel() * 1e3, quats[i].ravel()])
        for i in range(c.n_rows)]
    (tmp_path / "rig.csv").write_text("\n".join(rows) + "\n")
    assert main(["campaign", "import", str(tmp_path / "rig.csv"), "--robot", "ur10",
                 "--frame", "tool0", "--units", "angle=deg,length=mm", "--quiet", "--kind",
                 "poses", "--rotation-format", "quaternion", "--marker", "tip=tool0@0,30,50",
                 "--marker", "elbow=forearm_link@0,50,200", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    said = re.search(r"= \(([^)]*)\) has norm ([0-9.]+), not 1", err)
    assert said and "line 5" in err, err
    values = np.array([float(v) for v in said.group(1).split(",")])
    np.testing.assert_allclose(values, quats[3, 0], rtol=1e-5)
    assert float(said.group(2)) == pytest.approx(3.0, rel=1e-5)
