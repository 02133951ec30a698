"""A joint spring a link bend aliases (issue 35): the deflection diagnosis reports it as not
told apart from the bend's parameter, never with a one-sided bound read as if the bend were
not there. Kinova with joint 3 at 2000 N.m/rad, the bend joint_1 -> joint_3 forced in (one
fit, no search): its second axis is nearly joint 3's, the final fit puts joint 3's compliance
at its bound (1e14 N.m/rad) and the bend takes it; the spring's linearised one-sided interval
said "stiffness above 4805.9 N.m/rad" (truth 2000).
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from stiffness.calibration.diagnose import diagnose
from stiffness.calibration.diagnosis_page import render_diagnosis
from stiffness.elastic.model_file import load_model, read_model_file
from stiffness.errors import DataFileWarning
from stiffness.planning.simulate import simulate
from stiffness.provenance import provenance

KQ = [3e3, 3e3, 2e3, 1e3, 1e3, 1e3]  # N.m/rad
NOISE = 1e-5  # m
BEND = "link_compliance(j2s6s200_joint_1->j2s6s200_joint_3)"


@pytest.fixture(scope="module")
def d():
    """The diagnosis with the bend forced in (one fit, ~5 s), shared by the tests below."""
    c = simulate("kinova", kq=KQ, max_force=30.0, noise_std_m=NOISE, configs=6, seed=0).campaign
    return diagnose(c, families=(BEND,), max_steps=0, workers=1)


def test_a_spring_a_bend_aliases_is_reported_as_confounded_not_bounded(d):
    spring = next(p for p in d.final_stiffness if p.name == "j2s6s200_joint_3")
    (label, r), = spring.confounded_with
    assert label == f"{BEND}.stiffness_2" and abs(r) >= 0.9
    assert not spring.determined and all(math.isnan(v) for v in spring.ci95)
    text = spring.text()
    assert f"not told apart from {BEND}.stiffness_2 (correlation" in text
    assert "above" not in text and "rigid" not in text
    data = spring.to_dict()
    assert data["ci95"] == [None, None] and data["determined"] is False
    assert data["confounded_with"][0]["parameter"] == f"{BEND}.stiffness_2"
    # Independently, by finite differences of the model's predictions at the final fit: a
    # little compliance on joint 3 (1e-6 rad/(N.m), k 1e6 N.m/rad) and a little more on the
    # bend's second axis move the tool the same way (cosine of the two changes, all rows).
    fit = d.final
    assert fit.labels()[2] == "compliance(j2s6s200_joint_3)"
    assert fit.labels()[7] == f"{BEND}.stiffness_2"
    x = np.array(fit.x)
    spring, bend = x.copy(), x.copy()
    spring[2] = math.log(1e6)
    bend[7] *= 1.01
    moves = [np.ravel(fit.model.predict(v) - fit.model.predict(x)) for v in (spring, bend)]
    assert abs(moves[0] @ moves[1]) > 0.99 * np.linalg.norm(moves[0]) * np.linalg.norm(moves[1])
    # The other springs, which nothing aliases, keep their intervals.
    assert all(p.determined and not p.confounded_with for p in d.final_stiffness
               if p.name in ("j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_4"))
    # --json names it beside the identifiability's dropped parameters.
    (row,) = d.to_dict()["identifiability"]["confounded"]
    assert row["parameter"] == "compliance(j2s6s200_joint_3)"
    assert row["confounded_with"][0]["parameter"] == f"{BEND}.stiffness_2"
    assert "not told apart from" in row["note"]


def _joint_3_note(d) -> str:
    """The text report's phrase for joint 3, after its name."""
    text = next(p for p in d.final_stiffness if p.name == "j2s6s200_joint_3").text()
    return text.removeprefix("j2s6s200_joint_3 undetermined: ")


def test_the_page_names_what_the_spring_is_not_told_apart_from(d):
    """diagnosis.html says what the text says (the one phrase), not 'no upper bound'."""
    page = render_diagnosis(d.record(), None, provenance("stiffness diagnose kinova"))
    row = page[page.index("<td>j2s6s200_joint_3</td>"):]
    row = row[:row.index("</tr>")]
    note = _joint_3_note(d)
    assert note.startswith(f"the data do not bound it; not told apart from {BEND}.stiffness_2 "
                           "(correlation ") and note.endswith("N.m/rad, not a measurement)")
    assert f"<b>undetermined</b>: {note}" in row.replace("&gt;", ">")
    assert "no upper bound" not in row


def test_the_model_file_marks_the_spring_as_not_a_measurement(d, tmp_path):
    """final-model.json keeps joint 3's k_theta (where the fit left it) under
    undetermined_joints and names the bend's parameter in confounded_joints; loading it warns
    with the text report's phrase, not that the campaign did not load the joint. A file
    without confounded_joints (an older one) reads and warns as before."""
    path = d.model_file().write(tmp_path / "final-model.json")
    doc = json.loads(path.read_text())
    entry = doc["confounded_joints"]["j2s6s200_joint_3"]
    assert entry["confounded_with"][0]["parameter"] == f"{BEND}.stiffness_2"
    assert abs(entry["confounded_with"][0]["correlation"]) >= 0.9
    assert entry["note"] == _joint_3_note(d)
    assert list(doc["confounded_joints"]) == ["j2s6s200_joint_3"]
    plain = [j for j in doc["undetermined_joints"] if j != "j2s6s200_joint_3"]
    assert "j2s6s200_joint_3" in doc["undetermined_joints"]
    k3 = doc["k_theta"]["values"][doc["k_theta"]["joints"].index("j2s6s200_joint_3")]
    assert f"the fit left it at {k3:.5g} N.m/rad" in entry["note"]
    model = read_model_file(path)
    assert model.extra["confounded_joints"] == doc["confounded_joints"]  # kept as written
    assert model.to_dict(tmp_path)["confounded_joints"] == doc["confounded_joints"]
    with pytest.warns(DataFileWarning) as caught:
        load_model(path)
    said = [str(w.message) for w in caught if "is marked undetermined" in str(w.message)]
    assert said == [*[_plain(path, plain)] * bool(plain), f"{path}: the stiffness of "
                    f"j2s6s200_joint_3 is marked undetermined: {entry['note']}"]
    del doc["confounded_joints"]
    older = tmp_path / "older.json"
    older.write_text(json.dumps(doc))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_model(older)
    said = [str(w.message) for w in caught if "is marked undetermined" in str(w.message)]
    assert said == [_plain(older, doc["undetermined_joints"])]


def _plain(path, joints: list[str]) -> str:
    """The warning of springs the campaign did not load (older files: every undetermined one)."""
    return (f"{path}: the stiffness of {', '.join(joints)} is marked undetermined (its campaign "
            "did not load it): K_X in the directions it governs rests on an unidentified value")


def test_a_spring_bounded_only_from_below_is_not_called_unloaded(ur5_rigid_wrist_model):
    """A UR5 campaign loading a wrist spring of 1e13 N.m/rad (rigid to 5 um noise,
    ``ur5_rigid_wrist_model``): identify marks it undetermined with a 95 % interval open above.
    Loading its model file said 'its campaign did not load it', which it did; the file's value
    (where the fit stopped) read as a stiffness. Now the warning gives the interval's lower end
    and says the value is not a measurement."""
    path = ur5_rigid_wrist_model
    doc = json.loads(path.read_text())
    assert doc["undetermined_joints"] == ["wrist_1_joint"]
    k, low = doc["k_theta"]["values"][3], doc["k_theta"]["ci95"]["low"][3]
    assert doc["k_theta"]["ci95"]["high"][3] is None and 0 < low < k
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_model(path)
    said = [str(w.message) for w in caught if "wrist_1_joint" in str(w.message)]
    assert said == [f"{path}: the stiffness of wrist_1_joint is bounded by its "
                    f"campaign only from below (stiffer than {low:.3g} SI at 95 %, perhaps "
                    f"rigid): the file's {k:.3g} is where the fit stopped, not a measurement; "
                    "K_X in the directions it governs rests on it"], said
