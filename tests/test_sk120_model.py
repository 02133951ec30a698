"""The shipped SK120 against Table I's D-H chain and the paper's experimental constraints."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiffness.papers.sk120 import (
    FIXTURE_A_M,
    FIXTURE_B_M,
    AngleConvention,
    read_table1,
    sk120_urdf,
)
from stiffness.papers.tables import paper_configurations
from stiffness.robot.robot import load_robot
from stiffness.robot.sources import robots_directory


@pytest.fixture(scope="module")
def sk120():
    return load_robot("sk120")


@pytest.fixture(scope="module")
def convention():
    import json

    fit = json.loads((robots_directory() / "sk120" / "convention_fit.json").read_text())
    return AngleConvention(tuple(fit["chosen"]["signs"]), tuple(fit["chosen"]["offsets_deg"]))


def _dh(theta: float, d: float, a: float, alpha: float) -> pin.SE3:
    """Standard D-H transform Rz(theta) Tz(d) Tx(a) Rx(alpha), written independently."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    m = np.array([[ct, -st * ca, st * sa, a * ct],
                  [st, ct * ca, -ct * sa, a * st],
                  [0, sa, ca, d],
                  [0, 0, 0, 1.0]])
    return pin.SE3(m)


def _table1_chain(th: np.ndarray) -> pin.SE3:
    """Frame 0 -> tool flange through rows 1, 1b, 2b, 3b, 3, 4, 5, 6 of Table I (m, rad)."""
    return (_dh(th[0], 0, 0.215, -np.pi / 2) * _dh(th[2], 0, 0.542, 0)
            * _dh(th[1] - th[2], 0, 1.1, 0) * _dh(np.pi - (th[1] - th[2]), 0, 0.542, 0)
            * _dh(-np.pi / 2, 0, 0.25, -np.pi / 2) * _dh(th[3], 1.3, 0, -np.pi / 2)
            * _dh(th[4], 0, 0, np.pi / 2) * _dh(th[5], 0.23, 0, 0))


def test_shipped_urdf_is_the_generated_one(convention):
    table1 = read_table1(robots_directory() / "sk120" / "table1_dh.csv")
    shipped = (robots_directory() / "sk120" / "sk120.urdf").read_text()
    assert shipped == sk120_urdf(table1, convention)


def test_urdf_matches_table1_dh_chain(sk120, convention):
    rng = np.random.default_rng(3)
    tool = sk120.model.getFrameId("tool0")
    target = sk120.model.getFrameId("fixture_target")
    for _ in range(20):
        q_printed = np.deg2rad(rng.uniform([-180, -70, -115, -180, -120, -180],
                                           [180, 70, 35, 180, 120, 180]))
        q = sk120.configuration(q_printed)
        pin.framesForwardKinematics(sk120.model, sk120.data, q)
        expected = _table1_chain(convention.to_dh(q_printed))
        got = sk120.data.oMf[tool]
        assert np.allclose(got.homogeneous, expected.homogeneous, atol=1e-10)
        fixture = expected.act(np.array([FIXTURE_B_M, 0.0, FIXTURE_A_M]))
        assert np.allclose(sk120.data.oMf[target].translation, fixture, atol=1e-10)


def test_tool_vertical_at_every_printed_configuration(sk120):
    tool = sk120.model.getFrameId("tool0")
    for q_deg in paper_configurations():
        q = sk120.configuration(np.deg2rad(q_deg))
        pin.framesForwardKinematics(sk120.model, sk120.data, q)
        z_axis = sk120.data.oMf[tool].rotation[:, 2]
        # printed angles carry 4 decimals: q3 + q5 = -90 deg to 4e-4 deg
        assert z_axis[2] == pytest.approx(-1.0, abs=1e-7)


def test_parallelogram_keeps_forearm_orientation(sk120):
    """The forearm's orientation depends on q3 only (the parallelogram), not on q2.

    (q2 + q3 = -90 deg flattens the parallelogram: a loop singularity, avoided here.)
    """
    forearm = sk120.model.getFrameId("forearm")
    rotations = []
    for q2 in np.deg2rad([-60.0, -10.0, 40.0]):
        q = sk120.configuration(np.deg2rad([10.0, 0.0, -20.0, 0, -70, 0]) + [0, q2, 0, 0, 0, 0])
        pin.framesForwardKinematics(sk120.model, sk120.data, q)
        rotations.append(sk120.data.oMf[forearm].rotation.copy())
    assert np.allclose(rotations[0], rotations[1], atol=1e-10)
    assert np.allclose(rotations[0], rotations[2], atol=1e-10)
