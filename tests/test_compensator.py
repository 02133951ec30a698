"""The real-time compensator (issue 39): its command, solved anew by the exact equilibrium
solvers (:func:`stiffness.mechanics.equilibrium.solve_equilibrium` under the preloads,
:func:`stiffness.elastic.loaded.loaded_equilibrium` with link bends: Newton on the law's
residual, not the compensator's closed form), puts the loaded target on the wanted pose."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from stiffness.elastic.effects.parts import ElasticParts
from stiffness.elastic.loaded import loaded_equilibrium
from stiffness.elastic.model import ElasticModel
from stiffness.errors import RobotFileWarning, StiffnessError
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import load_robot

SK120_DH = str(Path(__file__).resolve().parents[1] / "examples" / "sk120-dh" / "robot.toml")


def _nonlinear_parts(robot, k, payload):
    """Springs ``k`` on the compliant joints, softening on the first, hardening and a
    backlash on the second and third, a payload (kg) with the links' weight."""
    joints = robot.compliant_joints
    parts = ElasticParts(dict(zip(joints, k, strict=True)),
                         beta={joints[0]: 1e-3, joints[1]: -2e-4},
                         backlash={joints[1]: 5e-4, joints[2]: 3e-4},
                         smoothing={joints[1]: 4.0, joints[2]: 2.0})
    parts.weigh(payload, np.array([0.01, -0.02, 0.05]))
    return parts


def _models():
    ur5 = load_robot("ur5")
    ur5_parts = _nonlinear_parts(ur5, [3e5, 3e5, 2e5, 4e4, 4e4, 4e4], 4.0)
    ur5_parts.add_compensator("shoulder_lift_joint", 2e5, 3000.0,
                              {"lever_m": 0.1, "base_m": 0.3})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        dh = load_robot(SK120_DH)
    panda = load_robot("panda", compliant_joints=[f"panda_joint{i}" for i in range(1, 8)])
    return {
        "ur5": ElasticModel.of_parts(ur5, ur5_parts),
        "sk120-dh": ElasticModel.of_parts(dh, _nonlinear_parts(
            dh, [1.4098e6, 4.0076e5, 9.3528e5], 60.0)),
        "panda": ElasticModel.of_parts(panda, _nonlinear_parts(
            panda, [3e5, 3e5, 2e5, 2e5, 5e4, 5e4, 5e4], 2.0)),
    }


MODELS = _models()


def _targets(em, count, seed):
    rng = np.random.default_rng(seed)
    base = np.asarray(em.robot.defaults.get("q_deg", np.zeros(em.robot.n_coordinates)))
    base = np.deg2rad(base) if "q_deg" in em.robot.defaults else base
    if em.robot.name == "ur5":
        base = np.array([0.1, -1.2, 1.5, -0.3, 1.57, 0.2])
    return base + rng.uniform(-0.4, 0.4, (count, em.robot.n_coordinates))


@pytest.mark.parametrize("name", list(MODELS))
def test_command_is_the_exact_equilibriums_inverse(name):
    """On random poses and wrenches, the exact equilibrium at the command (under the weight,
    the payload, the compensator, nonlinear springs, backlash and the coupling) rests every
    coordinate, hence the target pose, on the wanted one to 1e-9; the batched path gives the
    same commands; ignoring the nonlinear law or the weight would leave far more."""
    em = MODELS[name]
    comp = em.compensator()
    assert comp.fast and comp.method == "closed-form"
    rng = np.random.default_rng(7)
    targets = _targets(em, 4, seed=3)
    wrenches = np.hstack([rng.uniform(-300, 300, (4, 3)), rng.uniform(-10, 10, (4, 3))])
    commands = comp.command_path(targets, wrenches)
    robot = em.robot
    for target, wrench, batched in zip(targets, wrenches, commands, strict=True):
        out = np.empty(robot.n_coordinates)
        command = comp.command(target, wrench, out=out)
        assert command is out
        np.testing.assert_allclose(batched, command, rtol=0, atol=1e-14)
        eq = em.at(command, wrench).equilibrium()
        rest = robot.coordinates_of(eq.q)
        assert np.abs(rest - target).max() < 1e-9
        wanted, loaded = target_state(robot, robot.configuration(target)), target_state(
            robot, eq.q)
        assert np.linalg.norm(loaded.position - wanted.position) < 1e-9
        assert np.linalg.norm(pin.log3(loaded.rotation @ wanted.rotation.T)) < 1e-9
        # what is cancelled is large: the sag of the uncompensated arm
        sag = robot.coordinates_of(em.at(target, wrench).equilibrium().q) - target
        assert np.abs(sag).max() > 1e-4


def test_ur5_frame_and_offset_move_the_wrench_point():
    """A compensator for another target equals that of the model loaded with that target."""
    em = MODELS["ur5"]
    comp = em.compensator(frame="wrist_3_link", target_offset=[0.0, 0.05, 0.12])
    robot = load_robot("ur5", frame="wrist_3_link", target_offset=[0.0, 0.05, 0.12])
    other = ElasticModel(robot, em.law, payload=None, compensators=em.compensators)
    other._weighed = em._weighed
    target, wrench = _targets(em, 1, seed=5)[0], np.array([50.0, -80.0, -200.0, 1, 2, 3])
    np.testing.assert_allclose(comp.command(target, wrench),
                               other.compensator().command(target, wrench), atol=1e-15)
    assert np.abs(comp.command(target, wrench) - em.compensator().command(target, wrench)
                  ).max() > 1e-6


def test_link_bends_newton_holds_the_pose_and_warm_starts():
    """Link bends: Newton on the command; the loaded equilibrium at the command holds the
    pose to 1e-9; a neighbouring tick, warm started from the last correction, takes fewer
    steps than a cold start."""
    ur5 = load_robot("ur5")
    parts = ElasticParts(dict(zip(ur5.coordinate_joints, [3e5, 3e5, 2e5, 4e4, 4e4, 4e4],
                                  strict=True)), beta={"elbow_joint": 1e-3},
                         bends=[("elbow_joint", "wrist_1_joint", 5e4, 3e4)])
    em = ElasticModel.of_parts(ur5, parts)
    comp = em.compensator()
    assert comp.method == "general" and not comp.fast
    wrench = np.array([60.0, -30.0, -300.0, 2.0, 0.0, 1.0])
    target = np.array([0.1, -1.2, 1.5, -0.3, 1.57, 0.2])
    cold = []
    for step in range(3):
        q_target = target + 1e-4 * step  # a 1 kHz tick moves this much
        command = comp.command(q_target, wrench)
        cold.append(comp.iterations)
        loaded = loaded_equilibrium(em, command, wrench)
        wanted = target_state(ur5, ur5.configuration(q_target))
        assert np.linalg.norm(loaded.position - wanted.position) < 1e-9
        assert np.linalg.norm(pin.log3(loaded.rotation @ wanted.rotation.T)) < 1e-9
    assert max(cold[1:]) < cold[0]


def test_closed_loop_sk120_and_bad_input():
    """The closed-loop SK120 (closed form, each loop closed from the last tick): the exact
    equilibrium at the command holds the target to 1e-9; bad arguments: one-line errors."""
    sk120 = load_robot("sk120")
    em = ElasticModel.joint_springs(sk120, [1.4098e6, 4.0076e5, 9.3528e5])
    comp = em.compensator()
    assert not comp.fast
    wrench = np.asarray(sk120.defaults["wrench_SI"], dtype=float)
    target = np.deg2rad(np.asarray(sk120.defaults["q_deg"], dtype=float))
    command = comp.command(target, wrench)
    eq = em.at(command, wrench).equilibrium()
    wanted = target_state(sk120, sk120.configuration(target))
    assert np.linalg.norm(eq.position - wanted.position) < 1e-9
    for kwargs in ({"hold": "twist"}, {"method": "newton"}):
        with pytest.raises(StiffnessError) as err:
            em.compensator(**kwargs)
        assert "\n" not in str(err.value)
    with pytest.raises(StiffnessError):
        em.compensator(frame="no_such_frame")
