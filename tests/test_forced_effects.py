"""``diagnose --families`` on a deflection campaign (issue 35: one selection loop, the same
options for both kinds): effects forced in first, in order, whatever their BIC and held-out
error, never removed by the backward elimination, recorded under ``selection``."""

from __future__ import annotations

import json

import pytest

from stiffness.calibration.diagnose import diagnose
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.planning.simulate import simulate

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]


@pytest.fixture(scope="module")
def tilted():
    """UR5, three arm joints compliant, 6 configurations x 3 loads, 5 µm, the elbow's bearing
    tilting (2e4 N.m/rad about both axes)."""
    return simulate("ur5", kq=[3e4, 2e4, 1.5e4], max_force=100.0, configs=6,
                    compliant_joints=JOINTS, target_offset_m=[0.0, 0.0, 0.1],
                    loads_per_config=3, noise_std_m=5e-6, seed=2,
                    effects=["transversal_compliance:elbow_joint=2e4"])


def test_a_forced_effect_comes_first_and_stays(tilted):
    """``target_offset`` explains nothing here: unforced, the search names the tilt alone;
    forced, it is the first step, marked forced, and the backward elimination, which removes
    what the final model is better without, keeps it; the tilt is still named after it."""
    free = diagnose(tilted.campaign, propose=False, workers=1)
    assert [s.effect.label for s in free.named_steps] == ["transversal_compliance(elbow_joint)"]
    d = diagnose(tilted.campaign, propose=False, workers=1, families=["target_offset"])
    assert d.steps[0].effect.name == "target_offset" and d.steps[0].forced
    assert d.steps[0].delta_bic > 0  # it earns nothing: only forcing adds it
    assert [s.effect.label for s in d.named_steps] == [
        "target_offset", "transversal_compliance(elbow_joint)"]
    assert not any(s.forced for s in d.steps[1:])
    assert d.to_dict()["selection"] == {"forced": ["target_offset"], "forbidden": []}


def test_a_label_forces_its_place(tilted):
    """A label ``name(where)`` forces that place, not the best one (the shoulder's tilt for
    the elbow's); the search then finds the elbow's."""
    d = diagnose(tilted.campaign, propose=False, workers=1, max_steps=1,
                 families=["transversal_compliance(shoulder_lift_joint)"])
    assert [s.effect.label for s in d.steps] == ["transversal_compliance(shoulder_lift_joint)",
                                                 "transversal_compliance(elbow_joint)"]


def test_a_place_in_simulates_spelling_is_forced_or_forbidden(tilted):
    """``NAME:WHERE`` (simulate's spelling) names the place as ``NAME(WHERE)`` does, in
    ``--families`` and ``--not`` (it was refused: 'a place is written NAME(WHERE)'): the
    shoulder's tilt forced, the elbow's forbidden, the search names another effect there."""
    d = diagnose(tilted.campaign, propose=False, workers=1, max_steps=1,
                 families=["transversal_compliance:shoulder_lift_joint"],
                 not_families=["transversal_compliance:elbow_joint"])
    labels = [s.effect.label for s in d.steps]
    assert labels[0] == "transversal_compliance(shoulder_lift_joint)" and d.steps[0].forced
    assert "transversal_compliance(elbow_joint)" not in labels
    assert d.to_dict()["selection"] == {
        "forced": ["transversal_compliance(shoulder_lift_joint)"],
        "forbidden": ["transversal_compliance(elbow_joint)"]}


def test_forced_names_are_checked(tilted, tmp_path, capsys):
    """A name outside the library, one also forbidden (everywhere or at its place, in either
    spelling), a place with no candidate (in either spelling), a place not closed: one line
    each; the command line records --families in the model file."""
    for families, forbid, words in ((["target_ofset"], [], "not an effect of the library"),
                                    (["backlash"], ["backlash"], "both forced"),
                                    (["backlash:elbow_joint"], ["backlash(elbow_joint)"],
                                     "both forced"),
                                    (["backlash(wrist_3_joint)"], [], "no candidate"),
                                    (["backlash:wrist_3_joint"], [],
                                     r"backlash\(wrist_3_joint\): no candidate"),
                                    (["backlash(elbow_joint"], [], "closing bracket")):
        with pytest.raises(StiffnessError, match=words):
            diagnose(tilted.campaign, propose=False, workers=1, families=families,
                     not_families=forbid)
    folder = tmp_path / "campaign"
    tilted.write(folder)
    assert main(["diagnose", str(folder), "--families", "target_offset", "--max-steps", "0",
                 "--no-proposals", "--workers", "1", "--quiet", "--out",
                 str(tmp_path / "out")]) == 0
    assert "target_offset *" in capsys.readouterr().out
    model = json.loads((tmp_path / "out" / "final-model.json").read_text())
    assert model["selection"]["forced"] == ["target_offset"]
