"""A pose campaign in the wrong length unit is no calibration, and says so
(stiffness.calibration.pose_plausibility, docs/absolute-poses.md "Units").

Declared mm and written m, the joint placement errors shrink the robot 1000x and the fit
reads *explained to noise*: the diagnosis, identify and the model file they write must say
NOT A CALIBRATION with the unit and the fix. Declared m and written mm, the marker offsets
go tens of metres. A marker offset declared in m in a mm campaign (or the reverse) is
corrected by the fit and noted. A tracker 250 m away and millimetre placement errors are a
calibration: nothing said.
"""

from __future__ import annotations

import csv
import html
import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.calibration import pose_diagnosis
from stiffness.calibration.pose_campaign import (
    PoseCampaign,
    load_pose_campaign,
    write_pose_campaign,
)
from stiffness.calibration.pose_diagnose import CANDIDATES, PoseSearch, diagnose_poses
from stiffness.calibration.pose_fit import rows_of
from stiffness.calibration.pose_identify import identify_poses
from stiffness.calibration.pose_model import Marker, PoseModel, one_dof_joints
from stiffness.calibration.pose_page import render_pose_diagnosis
from stiffness.calibration.pose_plausibility import PLACEMENT_FRACTION
from stiffness.calibration.pose_report import format_pose_report
from stiffness.calibration.search import Stop
from stiffness.errors import DataFileWarning
from stiffness.planning.simulate_poses import HiddenPoseErrors, simulate_pose_campaign
from stiffness.provenance import provenance
from stiffness.robot.calibration import read_pose_calibration
from stiffness.robot.kinematics import reach as reach_of
from stiffness.robot.robot import load_robot
from stiffness.units import Units

MARKERS = [Marker("tip", "tool0", np.array([0.0, 0.03, 0.05])),
           Marker("elbow", "forearm_link", np.array([0.0, 0.05, 0.2]))]


def quietly(read):
    """``read()`` and the messages of the DataFileWarnings it raised."""
    with warnings.catch_warnings(record=True) as found:
        warnings.simplefilter("always")
        out = read()
    return out, [str(w.message) for w in found if issubclass(w.category, DataFileWarning)]


@pytest.fixture(scope="module")
def legit(tmp_path_factory) -> Path:
    """A rigid UR10 seen by a tracker 250 m away and turned, 0.4 mm placement errors, 10
    poses, two markers, 20 um noise, written in mm."""
    robot = load_robot("ur10", frame="tool0")
    rng = np.random.default_rng(3)
    eps = np.zeros((6, 6))
    eps[:, :2] = rng.normal(0.0, 4e-4, (6, 2))
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])),
                              np.array([250.0, -80.0, 30.0]),
                              np.array([m.offset for m in MARKERS]) + 1e-3, np.zeros(6), eps)
    campaign = simulate_pose_campaign(robot, MARKERS, hidden, 10, 20e-6, seed=1,
                                      units=Units("deg", "N", "mm"))
    folder = tmp_path_factory.mktemp("legit")
    write_pose_campaign(campaign, folder)
    return folder


def variant(source: Path, folder: Path, scale: float = 1.0,
            edits: tuple[tuple[str, str], ...] = ()) -> Path:
    """A copy of ``source`` with its marker positions times ``scale`` and, in its
    campaign.toml, each ``(old, new)`` text of ``edits`` replaced."""
    shutil.copytree(source, folder)
    toml = folder / "campaign.toml"
    text = toml.read_text()
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    toml.write_text(text)
    path = folder / "measurements.csv"
    rows = list(csv.reader(path.open()))
    cols = [i for i, name in enumerate(rows[0]) if name[-2:] in ("_x", "_y", "_z")]
    for row in rows[1:]:
        for i in cols:
            row[i] = repr(float(row[i]) * scale)
    with path.open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    return folder


#: The campaign toml in m: its unit, noise and offsets.
IN_M = (('length = "mm"', 'length = "m"'), ("noise_std = 0.02", "noise_std = 2e-05"),
        ("offset = [0.0, 50.0, 200.0]", "offset = [0.0, 0.05, 0.2]"))
#: The tip's offset written in m.
TIP_IN_M = (("offset = [0.0, 30.0, 50.0]", "offset = [0.0, 0.03, 0.05]"),)


def test_a_legit_calibration_far_from_the_tracker_is_plausible(legit):
    campaign, warned = quietly(lambda: load_pose_campaign(legit))
    assert warned == []
    d = diagnose_poses(campaign, families=["geometry"], max_steps=0)
    assert not d.unexplained and d.plausibility.plausible
    assert abs(d.plausibility.spread - 1.0) < 0.01
    text = format_pose_report(d)
    assert "NOT A CALIBRATION" not in text and "note: marker" not in text
    record = d.to_dict()
    assert record["plausible"] is True and record["plausibility"]["beyond"] == []


@pytest.fixture(scope="module")
def shrunk(legit, tmp_path_factory):
    """The campaign declared mm and written m, loaded (its warnings) and diagnosed with the
    geometry forced in."""
    folder = variant(legit, tmp_path_factory.mktemp("units") / "mm_is_m", 1e-3)
    campaign, warned = quietly(lambda: load_pose_campaign(folder))
    return diagnose_poses(campaign, families=["geometry"], max_steps=0), warned


def test_declared_mm_written_m_reads_explained_but_is_no_calibration(shrunk):
    """The geometry shrinks every link: 'explained to noise', and the verdict says no."""
    d, warned = shrunk
    assert len(warned) == 1 and 'the data look like m: [units] length = "m"' in warned[0]
    assert not d.unexplained  # the fit alone reads like a calibration
    p = d.plausibility
    assert not p.plausible and p.likely_unit == "m" and abs(p.spread - 1e-3) < 1e-5
    limit = PLACEMENT_FRACTION * p.reach_m
    assert any("placement" in b.parameter and abs(b.value) > limit for b in p.beyond)
    text = format_pose_report(d)
    verdict = next(line for line in text.splitlines() if line.startswith("NOT A CALIBRATION"))
    assert '[units] length = "m"' in verdict and "0.001 times as far" in verdict
    # the chi-square verdict, below the plausibility's (its words "explained to noise" until
    # the verdict became one sentence for both campaign kinds, 5 December 2026)
    assert text.index("NOT A CALIBRATION") < text.index("the final model explains the data to "
                                                        "noise")
    record = d.to_dict()
    assert record["plausible"] is False
    assert record["plausibility"]["likely_length_unit"] == "m"


def test_declared_m_written_mm(legit, tmp_path):
    """1000x too far: the markers' fitted offsets go metres beyond the reach."""
    folder = variant(legit, tmp_path / "m_is_mm", 1.0, IN_M + TIP_IN_M)
    campaign, _ = quietly(lambda: load_pose_campaign(folder))
    p = diagnose_poses(campaign, max_steps=0).plausibility
    assert not p.plausible and p.likely_unit == "mm"
    assert any(b.parameter.endswith("offset") and b.value > p.reach_m for b in p.beyond)
    assert '[units] length = "mm"' in p.verdict()


def test_identify_says_it_instead_of_sending_to_diagnose(shrunk):
    """identify's springs take a 1000x shrink: its text names the unit, not diagnose."""
    d, _ = shrunk
    identified = identify_poses(d.campaign)
    text = identified.format()
    assert text.splitlines()[3].startswith("NOT A CALIBRATION")
    assert '[units] length = "m"' in text and "run stiffness diagnose" not in text
    assert identified.to_dict()["plausibility"]["likely_length_unit"] == "m"


@pytest.mark.parametrize(("name", "scale", "edits", "unit", "declare"), [
    ("offset_in_m", 1.0, TIP_IN_M, "m", "in mm: offset = [0.0, 30.0, 50.0]"),
    ("offset_in_mm", 1e-3, IN_M, "mm", "in m: offset = [0.0, 0.03, 0.05]"),
])
def test_a_marker_offset_in_the_wrong_unit_is_noted(legit, tmp_path, name, scale, edits, unit,
                                                    declare):
    """The fit corrects it (a calibration), and a note names the unit and what to declare."""
    folder = variant(legit, tmp_path / name, scale, edits)
    campaign, warned = quietly(lambda: load_pose_campaign(folder))
    assert [w for w in warned if "beyond ur10's reach" in w] == ([] if unit == "m" else [
        w for w in warned if "tip 58.31 m from their frame" in w])
    d = diagnose_poses(campaign, families=["geometry"], max_steps=0)
    assert not d.unexplained and d.plausibility.plausible
    notes = d.plausibility.notes()
    assert len(notes) == 1 and f"looks like {unit}" in notes[0] and declare in notes[0], notes
    assert d.to_dict()["plausibility"]["marker_offsets"][0]["likely_length_unit"] == unit


def test_the_output_folder_and_the_model_file_say_it(shrunk, tmp_path, monkeypatch):
    """diagnose --out: the page's verdict, and the model file warns whoever reads it (the
    residual figures, seconds of plotting, left out)."""
    monkeypatch.setattr(pose_diagnosis, "marker_residual_plots", lambda d: None)
    d, _ = shrunk
    paths = d.write(tmp_path / "out", "stiffness diagnose mm_is_m")
    assert json.loads(paths["diagnosis"].read_text())["plausible"] is False
    assert "NOT A CALIBRATION" in paths["page"].read_text()
    _, warned = quietly(lambda: read_pose_calibration(paths["model"]))
    assert len(warned) == 1 and '[units] length = "m"' in warned[0]


@pytest.mark.parametrize("elbow_deg", [8.0, 1.0])
def test_a_zero_offset_beyond_a_few_degrees_is_implausible(elbow_deg):
    """A UR10 whose elbow encoder reads 8 deg off (the other zeros 0.3 deg off), 12 poses, two
    markers, 20 um noise: the fit finds the elbow's offset (its interval covers 8 deg), and
    the plausibility names it beyond the 5 deg limit (IMPLAUSIBLE ANGLES, plausible false,
    ``beyond_angles``; the lengths still plausible: no NOT A CALIBRATION). At 1 deg nothing is
    said. FIGAROH's TALOS right arm (39 poses) had +8.2 and -7.6 deg on arm_right_4/5."""
    robot = load_robot("ur10", frame="tool0")
    offsets = np.radians([0.3, -0.3, elbow_deg, 0.3, -0.3, 0.3])
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([2.0, -1.0, 0.5]),
                              np.array([m.offset for m in MARKERS]), offsets, np.zeros((6, 6)))
    campaign = simulate_pose_campaign(robot, MARKERS, hidden, 12, 20e-6, seed=4)
    d = diagnose_poses(campaign, families=["joint_offsets"], max_steps=0)
    labels = [p.label for p in d.final.model.parameters]
    k = labels.index("elbow_joint zero")
    low, high = d.final.interval()
    assert low[k] <= offsets[2] <= high[k]
    p = d.plausibility
    record = d.to_dict()["plausibility"]
    assert p.lengths_plausible and record["beyond"] == []
    if elbow_deg < 5.0:
        assert p.plausible and p.verdict() is None and record["beyond_angles"] == []
        assert "IMPLAUSIBLE" not in format_pose_report(d)
        return
    assert not p.plausible and [b.parameter for b in p.turned] == ["elbow_joint zero"]
    assert record["beyond_angles"][0]["unit"] == "rad"
    assert record["beyond_angles"][0]["limit"] == pytest.approx(np.radians(5.0))
    verdict = next(line for line in format_pose_report(d).splitlines()
                   if line.startswith("IMPLAUSIBLE ANGLES"))
    assert "elbow_joint zero +0.14 rad (+8" in verdict and "NOT A CALIBRATION" not in verdict


def forearm_held(wrist_deg: float) -> PoseCampaign:
    """A UR10 whose forearm keeps its direction over the campaign (shoulder_lift + elbow and
    shoulder_pan held within 0.03 rad, 15 poses, one marker, 20 um), its elbow's zero 8 deg
    off and wrist_1's ``wrist_deg``, wrist_2's and wrist_3's 0.3 deg."""
    robot = load_robot("ur10", frame="tool0")
    rng = np.random.default_rng(1)
    lift = rng.uniform(-1.5, -0.5, 15)
    q = np.column_stack([0.3 + rng.uniform(-0.03, 0.03, 15), lift,
                         1.0 - lift + rng.uniform(-0.03, 0.03, 15), rng.uniform(-2, 2, (15, 3))])
    offsets = np.radians([0.0, 0.0, 8.0, wrist_deg, 0.3, 0.3])
    markers = MARKERS[:1]
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([2.0, -1.0, 0.5]),
                              np.array([m.offset for m in markers]), offsets, np.zeros((6, 6)))
    return simulate_pose_campaign(robot, markers, hidden, 15, 20e-6, seed=1, coordinates=q)


@pytest.mark.parametrize("wrist_deg", [-7.5, 7.5])
def test_two_offsets_the_campaign_does_not_tell_apart_are_named_cancelling(wrist_deg):
    """A UR10 whose forearm keeps its direction over the campaign (shoulder_lift + elbow and
    shoulder_pan held within 0.03 rad, 15 poses, one marker, 20 um): opposite zero offsets
    on the parallel elbow and wrist_1 axes move the wrist by one translation, which the
    measuring frame takes, so the fit trades one for the other. Hidden +8 and -7.5 deg: both
    beyond the limit and named as cancelling, with their correlation, which a finite-difference
    Jacobian of the model's predictions gives too (cov = (J^T J)^-1). Hidden +8 and +7.5 deg
    (same correlation, values that add, not cancel): beyond the limit, not cancelling."""
    campaign = forearm_held(wrist_deg)
    d = diagnose_poses(campaign, families=["joint_offsets"], max_steps=0)
    p, fit = d.plausibility, d.final
    assert {b.parameter for b in p.turned} == {"elbow_joint zero", "wrist_1_joint zero"}
    labels = [par.label for par in fit.model.parameters]
    kept = fit.identifiability.kept
    rows = rows_of(fit.model, campaign)
    columns = []
    for i in kept:
        step = np.zeros(fit.model.size)
        step[i] = 1e-6
        ahead, behind = (fit.model.evaluate(fit.x + s, rows, jacobian=False)[0].ravel()
                         for s in (step, -step))
        columns.append((ahead - behind) / 2e-6)
    cov = np.linalg.inv(np.array(columns) @ np.array(columns).T)
    a, b = kept.index(labels.index("elbow_joint zero")), kept.index(
        labels.index("wrist_1_joint zero"))
    rho = cov[a, b] / np.sqrt(cov[a, a] * cov[b, b])
    assert rho < -0.95
    record = d.to_dict()["plausibility"]["cancelling"]
    if wrist_deg > 0:
        assert p.cancelling == () and record == [] and "cancel" not in p.verdict()
        return
    assert [c.parameters for c in p.cancelling] == [("elbow_joint zero", "wrist_1_joint zero")]
    assert p.cancelling[0].correlation == pytest.approx(rho, abs=1e-3)
    assert record[0]["unit"] == "rad" and record[0]["correlation"] == pytest.approx(rho, abs=1e-3)
    assert "elbow_joint zero and wrist_1_joint zero (+8 and -7.5 deg) cancel" in p.verdict()


@pytest.mark.parametrize("tilt_deg", [6.0, 4.0])
def test_a_base_tilt_beyond_a_few_degrees_is_implausible(tilt_deg):
    """A soft UR10 (springs 7.5e4-7.5e3 N.m/rad) on a base tilted ``tilt_deg`` about x and
    -1 deg about y, 20 poses, two markers, 20 um, 150 N payload, the base tilt fitted: its
    intervals cover both angles, and the plausibility names the x tilt beyond the 5 deg limit
    at 6 deg (IMPLAUSIBLE ANGLES, plausible false), nothing at 4 deg (fitted 6.27 deg [5.79,
    6.75] and 4.27 [3.79, 4.75]: about three standard errors from the limit). It fails with the
    limit removed (6 deg not named) or its comparison reversed (4 deg named)."""
    robot = load_robot("ur10", frame="tool0")
    tilt = np.radians([tilt_deg, -1.0])
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([2.0, -1.0, 0.5]),
                              np.array([m.offset for m in MARKERS]), np.zeros(6),
                              np.zeros((6, 6)), np.array([3e5, 2e5, 1.2e5, 4e4, 3e4, 3e4]) / 4,
                              base_tilt=tilt)
    campaign = simulate_pose_campaign(robot, MARKERS, hidden, 20, 20e-6, seed=2,
                                      payload=np.array([0.0, 0.0, -150.0, 0.0, 0.0, 0.0]))
    d = diagnose_poses(campaign, families=["joint_compliance", "base_tilt"], max_steps=0)
    table = {p["parameter"]: p for p in d.to_dict()["parameters"]}
    for axis, angle in zip(("rx", "ry"), tilt, strict=True):
        low, high = table[f"base tilt {axis}"]["interval_95"]
        assert low < angle < high
    p, record = d.plausibility, d.to_dict()["plausibility"]
    assert p.lengths_plausible
    if tilt_deg < 5.0:
        assert p.plausible and p.turned == () and record["beyond_angles"] == []
        return
    assert not p.plausible and [b.parameter for b in p.turned] == ["base tilt rx"]
    assert record["beyond_angles"][0]["limit"] == pytest.approx(np.radians(5.0))
    assert any(line.startswith("IMPLAUSIBLE ANGLES") and "base tilt rx" in line
               for line in format_pose_report(d).splitlines())


@pytest.mark.parametrize("forced", [False, True])
def test_diagnose_refuses_offsets_that_cancel_unless_forced(forced):
    """The forearm-held UR10 with its elbow and wrist_1 zeros +8 and -7.5 deg off (a pair the
    campaign does not tell apart, :func:`forearm_held`), joint_offsets the only family the
    search may try: its fit explains the poses to the 20 um noise (chi-square p > 0.05, the
    forced fit's) with both zeros beyond 5 deg and cancelling. A search names no such family
    (until 6 December 2026 it named it and only warned): it is refused before it is judged
    held out, and the stop reason, the families not added, ``best_rejected`` and the
    verdict's model say so; forced (``--families``), it is named and the verdict warns."""
    others = [f for f in CANDIDATES["known"] if f != "joint_offsets"]
    d = diagnose_poses(forearm_held(-7.5), families=["joint_offsets"] if forced else [],
                       not_families=others)
    record, report = d.to_dict(), format_pose_report(d)
    if forced:
        assert d.families[-1] == "joint_offsets" and d.gof() > 0.05
        assert not d.plausibility.plausible and len(d.plausibility.cancelling) == 1
        assert "IMPLAUSIBLE ANGLES" in report and "refused" not in report
        return
    assert d.families == ["frame", "markers"] and record["families"] == ["frame", "markers"]
    why = d.not_judged["joint_offsets"]
    assert why.startswith("unphysical: its fit turns elbow_joint zero +0.14 rad (+8")
    assert "wrist_1_joint zero -0.131 rad (-7.5" in why
    assert "elbow_joint zero and wrist_1_joint zero (+8 and -7.5 deg) cancel" in why
    assert d.stop_reason.startswith(PoseSearch.stops[Stop.REFUSED])
    assert f"joint_offsets not judged: {why}" in d.stop_reason
    assert record["best_rejected"]["candidate"] == "joint_offsets"
    assert record["best_rejected"]["not_judged"] == why and record["not_judged"] == {
        "joint_offsets": why}
    assert f"joint_offsets ({why})" in report and "IMPLAUSIBLE ANGLES" not in report
    assert d.plausibility.plausible


def test_a_step_records_the_family_it_refused_and_the_search_goes_on():
    """The same UR10, every family tried: joint_offsets, best by BIC, is refused in the step
    (the step's ``refused``, in ``--json`` and the steps table) and another family is added
    in its place; no angle of the final model is beyond its limit."""
    d = diagnose_poses(forearm_held(-7.5))
    record, report = d.to_dict(), format_pose_report(d)
    step = record["steps"][1]
    assert step["family"] != "joint_offsets" and "joint_offsets" not in d.families
    assert step["refused"]["joint_offsets"].startswith("unphysical: its fit turns elbow_joint")
    assert f"step 1 refused joint_offsets: {step['refused']['joint_offsets']}" in report
    page = html.unescape(render_pose_diagnosis(record, None, provenance("test")))
    assert f"<p>Step 1 refused joint_offsets: {step['refused']['joint_offsets']}</p>" in page
    assert d.plausibility.turned == () and record["plausibility"]["beyond_angles"] == []


def geometry_limits(robot, markers) -> dict[str, float]:
    """``geometry``'s length limit (m) of each of its parameters, by label."""
    model = PoseModel(robot, markers, ("frame", "markers", "geometry"),
                      (np.eye(3), np.zeros(3)))
    geometry = next(f for f in model.family_objects if f.name == "geometry")
    return dict(zip([p.label for p in model.parameters[model.slices()["geometry"]]],
                    geometry.plausible_lengths(model), strict=True))


def test_placement_limits_are_the_angle_limit_over_each_link():
    """``geometry``'s physical length limit (docs/absolute-poses.md, Implausible placements):
    tan(5 deg) times the link that carries the joint, as the URDF draws it (the distance from
    the previous joint; a joint at its parent's origin, its parent's link), at least a tenth
    of the reach; NaN for the turns. UR10: wrist_1 over the 0.5723 m forearm, 50.1 mm;
    wrist_2 over its 0.1149 m link, floored at 0.1 x 1.879 m, 16.4 mm. Panda: panda_joint2
    at panda_joint1's origin, over joint1's 0.333 m; panda_joint6 over joint5's
    (-0.0825, 0.384) m; panda_joint4's 82.5 mm link at the floor (0.1 x its reach, 1.4227 m)."""
    tan5 = np.tan(np.radians(5.0))
    limits = geometry_limits(load_robot("ur10", frame="tool0"), MARKERS)
    reach = 0.1273 + 0.220941 + np.hypot(0.1719, 0.612) + 0.5723 + 0.1149 + 0.1157 + 0.0922
    assert limits["wrist_1_joint placement z"] == pytest.approx(tan5 * 0.5723, rel=1e-4)
    assert limits["wrist_1_joint placement x"] == pytest.approx(tan5 * 0.5723, rel=1e-4)
    assert limits["elbow_joint placement x"] == pytest.approx(tan5 * np.hypot(0.1719, 0.612),
                                                              rel=1e-4)
    assert limits["wrist_2_joint placement x"] == pytest.approx(tan5 * 0.1 * reach, rel=1e-3)
    assert np.isnan(limits["wrist_1_joint placement rx"])
    panda = load_robot("panda")
    limits = geometry_limits(panda, [Marker("tip", "panda_link7", np.zeros(3))])
    assert limits["panda_joint2 placement x"] == pytest.approx(tan5 * 0.333, rel=1e-4)
    assert limits["panda_joint6 placement y"] == pytest.approx(tan5 * np.hypot(0.0825, 0.384),
                                                               rel=1e-4)
    assert limits["panda_joint4 placement x"] == pytest.approx(tan5 * 0.1 * reach_of(panda.model))


def test_a_placement_shifted_beyond_the_angle_limit_is_implausible_and_forced_warns():
    """The forearm-held UR10 (+8 and -7.5 deg on elbow and wrist_1, :func:`forearm_held`)
    with geometry forced in: the fit takes the cancelling pair in as an 81 mm shift of
    wrist_1's placement (the elbow's 8 deg over the 0.5723 m forearm is 80 mm), beyond the
    50.1 mm a 5 deg turn of that link moves it. It was plausible (below the unit check's tenth
    of the reach, 188 mm) until 6 December 2026; now IMPLAUSIBLE PLACEMENTS, plausible
    false, ``beyond_placements``; forced, the family stays named (a warning)."""
    d = diagnose_poses(forearm_held(-7.5), families=["geometry"], max_steps=0)
    assert d.families[-1] == "geometry"
    p, record = d.plausibility, d.to_dict()["plausibility"]
    assert p.lengths_plausible and p.turned == () and record["beyond"] == []
    assert not p.plausible and record["plausible"] is False
    shifted = record["beyond_placements"]
    assert shifted[0]["parameter"] == "wrist_1_joint placement z"
    assert 0.075 < shifted[0]["value"] < 0.087 and shifted[0]["unit"] == "m"
    assert shifted[0]["limit"] == pytest.approx(np.tan(np.radians(5.0)) * 0.5723, rel=1e-4)
    verdict = next(line for line in format_pose_report(d).splitlines()
                   if line.startswith("IMPLAUSIBLE"))
    assert verdict.startswith("IMPLAUSIBLE PLACEMENTS: the fit moves wrist_1_joint placement "
                              "z +0.08")
    assert "(limit 0.0501 m)" in verdict and "NOT A CALIBRATION" not in verdict


def test_diagnose_refuses_the_cancelling_pair_taken_in_as_a_placement():
    """The same UR10, every family tried: joint_offsets is refused (its angles), and geometry,
    which took the pair in as wrist_1's 81 mm shift and was named in its place until 6
    December 2026, is refused too (the step's ``refused``, the report's line); no placement
    of the final model is beyond its limit."""
    d = diagnose_poses(forearm_held(-7.5))
    record, report = d.to_dict(), format_pose_report(d)
    assert "geometry" not in d.families and "joint_offsets" not in d.families
    why = record["steps"][1]["refused"]["geometry"]
    assert why.startswith("unphysical: its fit moves wrist_1_joint placement z +0.08")
    assert f"step 1 refused geometry: {why}" in report
    assert record["plausibility"]["beyond_placements"] == []


def test_honest_placement_errors_on_a_wrist_are_named():
    """A panda (two joints at their parent's origin, two links of 83 and 88 mm under the
    floor) whose every placement is off by up to 3 mm and 0.5 deg (uniform draws), 40 poses,
    two markers, 20 um: diagnose names geometry, plausible, nothing refused."""
    robot = load_robot("panda")
    rng = np.random.default_rng(7)
    n = len(one_dof_joints(robot.model))
    eps = np.column_stack([rng.uniform(-3e-3, 3e-3, (n, 3)),
                           rng.uniform(-np.radians(0.5), np.radians(0.5), (n, 3))])
    markers = [Marker("tip", "panda_link7", np.array([0.0, 0.03, 0.15])),
               Marker("elbow", "panda_link4", np.array([0.0, 0.05, 0.1]))]
    hidden = HiddenPoseErrors(pin.exp3(np.array([0.1, -0.2, 1.0])), np.array([2.0, -1.0, 0.5]),
                              np.array([m.offset for m in markers]), np.zeros(n), eps)
    campaign = simulate_pose_campaign(robot, markers, hidden, 40, 20e-6, seed=3)
    d = diagnose_poses(campaign)
    record = d.to_dict()
    assert "geometry" in d.families and d.plausibility.plausible
    assert all("geometry" not in s["refused"] for s in record["steps"])
    assert record["plausibility"]["beyond_placements"] == []
