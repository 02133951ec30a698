"""The fitting engine (stiffness.calibration.fitting): parameters the data do not see."""

from __future__ import annotations

import numpy as np

from stiffness.calibration.effects import Geometry, Model, References, make_effect
from stiffness.calibration.fitting import fit_model
from stiffness.model.robot import load_robot

K_TRUE = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
NOISE = 5e-6


def _campaign_model(compliant: tuple[str, ...]):
    """A UR5 model over tool0 (the wrist-3 axis passes through it: that stiffness is unseen)
    with a backlash on the shoulder, and noisy deflections of the six-joint truth."""
    robot = load_robot("ur5")
    geo = Geometry.of(robot)
    rng = np.random.default_rng(11)
    coords = np.repeat(rng.uniform(-1.5, 1.5, (20, 6)), 4, axis=0)
    forces = rng.normal(size=(80, 3)) * 100.0
    rows = geo.rows(coords, forces)
    refs = References.of(geo, rows, 1e5, np.full((1, 3), 1e-3))
    backlash = make_effect("backlash", "shoulder_lift_joint", geo)
    truth = Model(geo, rows, "enhanced", tuple(robot.compliant_joints), (backlash,), refs)
    measured = truth.predict(np.concatenate([np.log(K_TRUE), [2.0]]))
    measured = measured + rng.normal(size=measured.shape) * NOISE
    return Model(geo, rows, "enhanced", compliant, (backlash,), refs), measured


def test_an_unseen_stiffness_is_held_and_the_others_fit_as_without_it():
    robot = load_robot("ur5")
    joints = tuple(robot.compliant_joints)
    model, measured = _campaign_model(joints)
    x0 = np.concatenate([np.log(K_TRUE * 1.3), [0.5]])
    fit = fit_model(model, measured, NOISE, x0, x_scale=1.0)
    assert fit.x[5] == x0[5]  # wrist_3_joint: held where it started
    # the same fit with that joint rigid (an independent model without it)
    five, _ = _campaign_model(joints[:5])
    reduced = fit_model(five, measured, NOISE, np.delete(x0, 5), x_scale=1.0)
    np.testing.assert_allclose(fit.cost, reduced.cost, rtol=1e-9)
    np.testing.assert_allclose(np.delete(fit.x, 5), reduced.x, rtol=1e-6)
    # and the solver does not crawl along the unseen direction
    assert fit.nfev <= 60
    assert fit.cost < 1.5 * measured.size  # it fits to noise
