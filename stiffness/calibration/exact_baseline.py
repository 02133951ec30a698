"""The deflection fit's ``exact`` baseline as an observation of the pose model (issue 35).

``identify --formulation exact`` fits the exact elastostatic equilibrium of every row,
``K dtheta = J(theta)^T W`` (A&S eq. 9), linear springs on the campaign's compliant joints and
nothing else. That equilibrium is the pose model's sag
(:class:`~stiffness.calibration.pose_model.PoseModel` with ``joint_compliance`` alone, its
fixed point ``Delta q = C tau(q + Delta q)``, on a robot with loops each pass closed with all
rows at once) on the robot without gravity, the rows' wrenches applied at the target:
:class:`ExactObservation` observes the target there, loaded minus unloaded (without gravity an
unloaded row does not sag: its configuration is the commanded one). Its position, the rotation
vector ``phi = log(R R_0^T)`` of its frame and their derivatives (the rotation's through the
inverse Jacobian of ``log``: ``d phi = Jlog3(R R_0^T) R_0 R^T J_w d theta``) come from the
batch kernels at the sag's configurations (:func:`stiffness.batch.kernels.batch_kinematics`:
the target's Jacobian over the springs and ``K_C``), moved by the sag's last step (at most
:data:`~stiffness.calibration.pose_model.SAG_TOLERANCE`, to first order) to its converged value.

The derivatives are the implicit function theorem's on the equilibrium,
``d dtheta / d ln k_i = -(K - K_C)^-1 e_i k_i dtheta_i``: the pose model's ``joint_compliance``
columns (the torques at the loaded configuration held fixed) carried through the sag's own
change, ``(I - C K_C)^-1``, which they leave out. With ``K_C`` of the rows' wrenches at
equilibrium, ``K - K_C`` must be positive definite there (a stable equilibrium).

Units: SI (m, N, rad; ``k`` N.m/rad or N/m).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from stiffness.batch.kernels import batch_kinematics
from stiffness.calibration.pose_model import Loads, Marker, PoseModel
from stiffness.elastic.effects.geometry import cached_robot
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.elastic.effects.pose_face import compliance_label
from stiffness.errors import ConvergenceError, UnstableEquilibriumError
from stiffness.robot.robot import TARGET_FRAME, Robot


def weightless(robot: Robot) -> Robot:
    """A copy of ``robot`` with gravity zero (its own Pinocchio model and data; the loop
    declaration shared: closures do not read gravity)."""
    model = pin.Model(robot.model)
    model.gravity = pin.Motion.Zero()
    return replace(robot, model=model, data=model.createData())


class ExactObservation:
    """The exact equilibria of a hypothesis's rows and their derivatives in ``ln k``, observed on
    the pose model's sag (module docstring).

    Parameters
    ----------
    model
        An ``exact`` :class:`~stiffness.elastic.effects.hypothesis.Hypothesis`: its rows (their
        configurations and wrenches), compliant joints and rotation weight.
    """

    def __init__(self, model: Hypothesis) -> None:
        robot = model.geometry.robot
        if model.joints != tuple(robot.compliant_joints):  # the baseline's springs alone
            robot = cached_robot(robot.name, robot.target_frame, tuple(robot.target_offset),
                                 model.joints, robot.loop_file, robot.fixed_base)
        rows = model.rows
        closed: dict[int, np.ndarray] = {}  # each configuration closed once
        for i in range(rows.n_rows):
            c = int(rows.config_index[i])
            if c not in closed:
                closed[c] = robot.configuration(rows.coords[i])
        q0 = np.array([closed[int(c)] for c in rows.config_index])
        self.robot = weightless(robot)
        self.sag = PoseModel(self.robot, [Marker("target", TARGET_FRAME)], ("joint_compliance",),
                             (np.eye(3), np.zeros(3)), Loads(TARGET_FRAME, np.zeros((0, 6))))
        labels = [p.label for p in self.sag.parameters]
        self.columns = [labels.index(compliance_label(j)) for j in model.joints]
        self.wrench = model.wrench
        # the same row objects at every evaluation: each starts from its last converged sag
        self.rows = [self.sag.row_terms(q, w) for q, w in zip(q0, self.wrench, strict=True)]
        self.unloaded = batch_kinematics(self.robot, q0, pose=True)
        #: the spring coordinates of a sag on the independent coordinates
        self.to_springs = np.linalg.pinv(self.sag.spring_map)
        self.rotation_weight = model.rotation_weight

    def __call__(self, k: np.ndarray, jacobian: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted rows (m, 3) ``dx`` (m) or, with a rotation weight ``w``, (m, 6)
        ``[dx; w dphi]`` at the stiffnesses ``k`` (SI, the hypothesis's joints), and with
        ``jacobian`` their derivatives (m, 3 or 6, n) in ``ln k``.

        Raises
        ------
        ConvergenceError
            If the sag does not converge for some row (the load may exceed its buckling load).
        UnstableEquilibriumError
            If ``K - K_C`` is not positive definite at some row's equilibrium.
        """
        x = np.zeros(self.sag.size)
        x[self.columns] = 1.0 / k
        try:
            state, step = self.sag.loaded_state(x, self.rows)
        except ConvergenceError as exc:
            raise ConvergenceError(
                "the exact equilibrium of some row is not found (the sag does not converge): "
                "the load may exceed the buckling load; reduce it or stiffen the joints"
            ) from exc
        kin = batch_kinematics(self.robot, state.q, pose=True)
        assert kin.position is not None and kin.rotation is not None  # pose asked for
        last = np.einsum("mkn,mn->mk", kin.jacobian, step @ self.to_springs.T)
        base = self.unloaded
        assert base.position is not None and base.rotation is not None  # pose asked for
        dx = kin.position - base.position + last[:, :3]
        w = self.rotation_weight
        if w is None:
            pred, out = dx, kin.jacobian[:, :3]
        else:  # the rotation vector phi = log(R R_0^T) and its derivative d phi / d omega
            turn = np.einsum("mab,mcb->mac", kin.rotation, base.rotation)
            d_log = np.array([pin.Jlog3(t) @ t.T for t in turn])
            rotation = (np.array([pin.log3(t) for t in turn])
                        + np.einsum("mab,mb->ma", d_log, last[:, 3:]))
            pred = np.hstack([dx, w * rotation])
            out = np.concatenate([kin.jacobian[:, :3], w * d_log @ kin.jacobian[:, 3:]], axis=1)
        kmat = np.diag(k)
        tangent = kmat - np.einsum("mk,mkab->mab", self.wrench, kin.k_c_basis)
        _check_stable(tangent)
        if not jacobian:
            return pred, None
        # implicit function theorem: d dtheta / d ln k_i = -(K - K_C)^-1 e_i k_i dtheta_i
        dtheta = np.einsum("mkn,mk->mn", kin.jacobian, self.wrench) / k
        return pred, out @ -np.linalg.solve(tangent, dtheta[:, :, None] * kmat)


def _check_stable(tangent: np.ndarray) -> None:
    """Raise :class:`UnstableEquilibriumError` naming the first row whose tangent stiffness
    ``K - K_C`` (m, n, n) at its equilibrium is not positive definite."""
    lowest = np.linalg.eigvalsh(0.5 * (tangent + np.swapaxes(tangent, -1, -2)))[:, 0]
    if np.any(lowest <= 0):
        i = int(np.argmin(lowest))
        raise UnstableEquilibriumError(
            f"the equilibrium found under the load of row {i + 1} is unstable (K_theta - K_C "
            f"has the eigenvalue {lowest[i]:.3g} there): the load exceeds the buckling load of "
            "the robot in this configuration; reduce the load or stiffen the joints")
