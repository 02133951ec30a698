"""Deflection campaigns of a robot whose link masses are unknown (``diagnose --masses unknown``):
the weight is ``gravity_lumped``, the links' gravity parameters fitted, on springs on the chain
and on a ``[controller]``'s coordinates (tests/data/torso-passive, ``springs_on =
"controller"``).

The reference of the lumped weight is the weight of the URDF's inertias as Pinocchio's
``computeGeneralizedGravity`` and its derivatives give it (``gravity_preload``), never the
regressor the effect is built from.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stiffness.calibration.selection import fit_model
from stiffness.cli.main import main
from stiffness.elastic.effects import candidates, make_effect
from stiffness.elastic.effects.base import effect_variables
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.model_file import load_model
from stiffness.errors import StiffnessError
from stiffness.planning.simulate import simulate
from stiffness.robot.robot import load_robot

TORSO = Path(__file__).parent / "data" / "torso-passive" / "robot.toml"
K_TORSO = [4.0e4, 2.5e4, 2.0e4, 8.0e3, 6.0e3]


def _urdf_parameters(robot, links: tuple[str, ...]) -> np.ndarray:
    """The URDF's gravity parameters (m, m c_x, m c_y, m c_z) of ``links``' bodies."""
    out = []
    for name in links:
        inertia = robot.model.inertias[robot.model.getJointId(name)]
        out += [inertia.mass, *(inertia.mass * np.asarray(inertia.lever))]
    return np.array(out)


@pytest.mark.parametrize(("source", "compliant", "angles"), [
    ("ur5", ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint"), "motor"),
    ("ur5", ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint"), "link"),
    (str(TORSO), None, "motor"),
])
def test_lumped_weight_at_the_urdf_masses_is_the_robot_weight(source, compliant, angles):
    """With the URDF's own gravity parameters, ``gravity_lumped`` predicts every row as
    ``gravity_preload`` without payload does (the weight of the same inertias through RNEA),
    to 1e-9 of the deflection, on chain springs (motor and link angles) and on controller
    springs. Measured: 1e-15 relative."""
    robot = load_robot(source, compliant_joints=compliant)
    geo = Geometry.of(robot)
    rng = np.random.default_rng(3)
    coords = rng.uniform(-1.0, 1.0, (4, robot.n_coordinates)).repeat(2, axis=0)
    rows = geo.rows(coords, rng.normal(0.0, 60.0, (8, 3)), joint_angles=angles)
    refs = References.of(geo, rows, 2e4, np.full((1, 3), 1e-4))
    k = np.log(np.full(len(robot.compliant_joints), 2e4))

    def predicted(name: str, values: np.ndarray) -> np.ndarray:
        effect = make_effect(name, None, geo)
        model = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints), (effect,),
                           refs)
        return model.predict(np.concatenate([k, effect_variables(effect, values, refs)]))

    lumped = make_effect("gravity_lumped", None, geo)
    assert len(lumped.links) >= 3 and lumped.n_params == 4 * len(lumped.links)
    truth = predicted("gravity_preload", np.zeros(4))
    weightless = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints), (),
                            refs).predict(k)
    assert np.abs(truth - weightless).max() > 1e-3 * np.abs(truth).max()  # the weight shows
    gap = np.abs(predicted("gravity_lumped", _urdf_parameters(geo.robot, lumped.links))
                 - truth).max()
    assert gap < 1e-9 * np.abs(truth).max(), gap


def test_lumped_weight_fits_a_hidden_weight_on_controller_springs():
    """A torso campaign (springs on the controller's five coordinates, the links' weight and
    a 2 kg payload hidden, 6 poses x 4 loads, 1 um noise): the enhanced baseline with
    ``gravity_lumped`` fits to the noise, the baseline alone does not, and with the masses
    unknown ``gravity_lumped`` replaces ``gravity_preload`` among the candidates. Measured
    (seed 0): residual 1.0 x noise with it, 2.9 x without."""
    run = simulate(str(TORSO), kq=K_TORSO, effects=["gravity_preload=2"], configs=6,
                   loads_per_config=4, noise_std_m=1e-6, seed=0)
    c = run.campaign
    geo = Geometry.of(c.robot())
    rows = geo.rows(c.q, c.force, c.moment)
    refs = References.of(geo, rows, 2e4, c.deflection)
    base = Hypothesis(geo, rows, "enhanced", tuple(c.robot().compliant_joints), (), refs)
    names = {e.name for e in candidates(base, masses="unknown")}
    assert "gravity_lumped" in names and "gravity_preload" not in names
    start = np.log(np.array(K_TORSO))
    without = fit_model(base, c.deflection, 1e-6, start)
    lumped = base.extended(make_effect("gravity_lumped", None, geo))
    with_it = fit_model(lumped, c.deflection, 1e-6, base.extend_x(without.x,
                                                                  lumped.effects[-1]))
    assert with_it.rms() / 1e-6 < 1.3 < 2.0 < without.rms() / 1e-6, (with_it.rms(),
                                                                       without.rms())


def test_lumped_weight_model_file_reads_back(tmp_path):
    """A model file holding ``gravity_lumped`` (at the URDF's gravity parameters) is read by
    ``load_model``: the lumped weight is listed as not applied to the robot (its parameters
    are the combinations a campaign determines, which the robot's inertias cannot hold), and
    its fitted prediction equals that of the file holding ``gravity_preload`` without payload
    (to 1e-9)."""
    from stiffness.elastic.effects.base import Parameter
    from stiffness.elastic.model_contents import ModelEffect, ModelFile

    arm = ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint")
    geo = Geometry.of(load_robot("ur5", compliant_joints=arm))
    links = make_effect("gravity_lumped", None, geo).links
    values = _urdf_parameters(geo.robot, links)
    lumped = ModelEffect("gravity_lumped", None, "preload", [
        Parameter(f"{link}_{p}", v, 0.0, (v, v), "kg" if p == "m" else "kg.m")
        for (link, p), v in zip([(k, p) for k in links for p in ("m", "mcx", "mcy", "mcz")],
                                values, strict=True)], {"links": list(links)})
    preload = ModelEffect("gravity_preload", None, "preload", [
        Parameter(n, 0.0, 0.0, (0.0, 0.0), u) for n, u in zip(
            ("mass", "com_x", "com_y", "com_z"), ("kg", "m", "m", "m"), strict=True)])
    q, load = np.array([0.3, -1.2, 1.4, -0.9, 1.2, 0.1]), np.array([30.0, -20.0, -60.0])
    predicted = []
    for effect in (lumped, preload):
        file = ModelFile(source="ur5", frame="tool0", target_offset_m=[0.0, 0.0, 0.1],
                         compliant_joints=arm, k_theta=[3e3, 2e3, 1.5e3],
                         units=("N.m/rad",) * 3, formulation="enhanced", effects=(effect,),
                         noise_std_m=5e-6, noise_source="declared", campaign="test",
                         produced_by="diagnose")
        model = load_model(file.write(tmp_path / f"{effect.name}.json"))
        predicted.append(model.fitted(q, load))
    assert [e.label for e, _ in model.not_applied] == [] and len(model.applied) == 1
    assert [e.label for e, _ in load_model(tmp_path / "gravity_lumped.json").not_applied
            ] == ["gravity_lumped"]
    assert np.allclose(predicted[0], predicted[1], rtol=1e-9, atol=0.0), predicted


def test_diagnose_takes_masses_for_a_deflection_campaign(tmp_path, capsys):
    """``stiffness diagnose --masses unknown`` on a deflection campaign runs and says so in
    its ``--json`` (the baseline only: the search is tested above through its candidates)."""
    run = simulate(str(TORSO), kq=K_TORSO, configs=3, loads_per_config=2, seed=0)
    folder = run.write(tmp_path / "campaign")
    assert main(["diagnose", str(folder), "--masses", "unknown", "--max-steps", "0",
                 "--no-proposals", "--workers", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["masses"] == "unknown"


def test_the_lumped_weight_is_not_simulated_and_masses_are_checked():
    """``simulate --effect gravity_lumped`` is refused (the simulator hides the weight of
    known inertias, gravity_preload), as is a ``masses`` that is not known or unknown."""
    from stiffness.calibration.diagnose import diagnose

    with pytest.raises(StiffnessError, match="gravity_lumped is not simulated"):
        simulate(str(TORSO), kq=K_TORSO, effects=["gravity_lumped"], configs=2,
                 loads_per_config=1)
    with pytest.raises(StiffnessError, match="masses must be one of known, unknown"):
        diagnose(TORSO, masses="some")
