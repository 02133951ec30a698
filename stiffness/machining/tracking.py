"""The compensator proven in MuJoCo: a path tracked raw and compensated by an independent engine.

:func:`track` exports the robot of an elastic model with its springs and masses
(:func:`stiffness.robot.mjcf.robot_mjcf`, what ``stiffness robot export --mjcf`` writes; the
payload's mass on the target's body when the model carries the weight) and drives it in MuJoCo
along a joint path (``PATH.csv`` of ``stiffness compensate``) under the process wrench, once
commanding the path itself and once the compensator's command each tick
(:meth:`stiffness.elastic.model.ElasticModel.compensator`), and reports the target's error from
where the unloaded program puts it.

The controller (:class:`MujocoArm`): a stiff position loop on the motor side. Each tick the
springs' rest positions (``qpos_spring`` of the joint springs, ``tendon_lengthspring`` of
springs on a ``[controller]``'s coordinates) are the command, which is what the elastostatic
model means by a command; the joints are damped relative to the command's motion (critical
damping, with the command's velocity fed forward, so that damping leaves no lag), and each
joint gets a rotor inertia (``armature``) that keeps the explicit springs stable at the time
step. Neither changes the statics. The path is followed point to point with a smooth
(cosine) blend of ``segment_time`` per segment, after the robot settled at the first point.

MuJoCo simulates linear joint springs, the links' weight and the wrench: a model with other
effects (nonlinear laws, backlash, bends, spring compensators) cannot be its truth here. The
compensator may come from another model (:func:`track`'s ``compensator_model``: an identified
one, while MuJoCo simulates the truth).

Units: SI (m, N, rad, s).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from stiffness.elastic.model import ElasticModel
from stiffness.elastic.model_file import load_model
from stiffness.errors import StiffnessError, wrong_argument
from stiffness.files import atomic_write_with
from stiffness.machining.compensation import check_path_limits, path_and_wrench, point_wrenches
from stiffness.robot.mjcf import joint_value, robot_mjcf, spring_plan
from stiffness.robot.robot import TARGET_FRAME, Robot
from stiffness.units import float_array

#: Time step of the simulation (s).
TIMESTEP = 1e-3
#: The rotor inertia keeps each spring's explicit step below this ``omega dt``.
OMEGA_DT = 0.5


def exported_robot(em: ElasticModel) -> tuple[Robot, bool]:
    """The robot MuJoCo simulates for ``em`` (its Pinocchio model with the payload when the
    model carries the weight) and whether gravity acts.

    Raises
    ------
    StiffnessError
        A model MuJoCo cannot simulate: closed loops, nonlinear laws, backlash, link bends,
        compensators.
    """
    if not em.robot.loop.is_open_chain:  # before any path check: no path can make it run
        raise StiffnessError(
            f"{em.robot.title} has closed loops, which MuJoCo closes only by soft constraints "
            "that give way under load more than its joint springs: track simulates open "
            "chains only (a serial arm's parallelogram may be written as a coupling of the "
            "controller's coordinates, as examples/sk120-dh does)")
    law = em.compliant_law()
    beyond = [what for what, present in (
        ("nonlinear springs", np.any(law.beta != 0)), ("backlash", np.any(law.backlash != 0)),
        ("link bends", bool(em.links)), ("spring compensators", bool(em.compensators)))
        if present]
    if beyond:
        raise StiffnessError(f"MuJoCo simulates linear joint springs and the weight; this model "
                             f"has {', '.join(beyond)}: give track a model of joint springs "
                             "(the compensator may come from another, compensator_model)")
    if em.payload is None:
        return em.robot, False
    weighed = em._weighed
    assert weighed is not None  # set with the payload
    return replace(em.robot, model=weighed, data=weighed.createData()), True


class MujocoArm:
    """The exported robot in MuJoCo, its springs' rest driven by a command (see the module
    docstring).

    Parameters
    ----------
    em
        The elastic model MuJoCo simulates (:func:`exported_robot`).
    start
        Coordinates (rad, m) of the first command: the springs' rest and the first pose.
    timestep
        Simulation step (s).
    """

    def __init__(self, em: ElasticModel, start: np.ndarray, timestep: float = TIMESTEP) -> None:
        import mujoco

        self._mj = mujoco
        robot, gravity = exported_robot(em)
        self.robot = robot
        springs = dict(zip(robot.compliant_joints, em.k_theta.tolist(), strict=True))
        q0 = em.robot.configuration(np.asarray(start, dtype=float))
        m = mujoco.MjModel.from_xml_string(robot_mjcf(robot, springs, q0))
        m.opt.timestep = timestep
        m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        if not gravity:
            m.opt.gravity[:] = 0.0
        self.m, self.d = m, mujoco.MjData(m)
        model = robot.model
        self._joints = [model.joints[model.getJointId(m.joint(j).name)] for j in range(m.njnt)]
        self._spring = np.flatnonzero(m.jnt_stiffness > 0)
        plan = spring_plan(robot, springs)
        names = [m.joint(j).name for j in range(m.njnt)]
        self._tendons = np.zeros((m.ntendon, m.njnt))
        for i, (_, coefficients, _) in enumerate(plan.tendons):
            for joint, c in coefficients.items():
                self._tendons[i, names.index(joint)] = c
        self._site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, TARGET_FRAME)
        # hinges and slides only (the export's): joint j is dof j
        stiffness = m.jnt_stiffness + (m.tendon_stiffness[:, None] * self._tendons ** 2).sum(0)
        self.damping = np.zeros(m.nv)
        self.reset(start)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, self.d, full)
        inertia = np.diag(full).copy()
        m.dof_armature[:] = np.maximum(0.0, stiffness * (timestep / OMEGA_DT) ** 2 - inertia)
        self.damping = 2.0 * np.sqrt(stiffness * (inertia + m.dof_armature))
        m.dof_damping[:] = self.damping
        self._values = self.joint_values(start)
        self._feedforward = np.zeros(m.nv)

    def joint_values(self, coords: np.ndarray) -> np.ndarray:
        """MuJoCo's joint values (rad, m) at the coordinates ``coords``."""
        q = self.robot.configuration(np.asarray(coords, dtype=float))
        return np.array([joint_value(j, q) for j in self._joints])

    def reset(self, coords: np.ndarray) -> None:
        """At rest at ``coords``, the springs at rest there."""
        mujoco = self._mj
        self.d.qpos[:] = self.joint_values(coords)
        self.d.qvel[:] = 0.0
        self._values = self.d.qpos.copy()
        self.command(coords, velocity=False)
        mujoco.mj_forward(self.m, self.d)

    def command(self, coords: np.ndarray, velocity: bool = True) -> None:
        """Command ``coords`` (rad, m): the springs' rest there; the damping's reference
        velocity that of the command since the last one (``velocity``)."""
        values = self.joint_values(coords)
        m = self.m
        m.qpos_spring[m.jnt_qposadr[self._spring]] = values[self._spring]
        if m.ntendon:
            m.tendon_lengthspring[:] = (self._tendons @ values)[:, None]
        rate = (values - self._values) / m.opt.timestep if velocity else 0.0 * values
        self._feedforward = self.damping * rate  # one dof per joint, same order
        self._values = values

    def step(self, wrench: np.ndarray) -> None:
        """One step under the dead ``wrench`` (6,) (N, N.m, base axes) at the target."""
        d = self.d
        d.qfrc_applied[:] = self._feedforward
        self._mj.mj_applyFT(self.m, d, wrench[:3], wrench[3:], d.site_xpos[self._site],
                            self.m.site_bodyid[self._site], d.qfrc_applied)
        self._mj.mj_step(self.m, d)

    def settle(self, wrench: np.ndarray, max_steps: int = 200_000,
               velocity: float = 1e-13) -> np.ndarray:
        """Step under ``wrench`` until every joint velocity is below ``velocity`` (rad/s, m/s);
        returns the target's position (m).

        Raises
        ------
        StiffnessError
            Not at rest within ``max_steps``.
        """
        self._feedforward = np.zeros(self.m.nv)
        for step in range(max_steps):
            self.step(wrench)
            if step > 10 and np.abs(self.d.qvel).max() < velocity:
                return self.position()
        raise StiffnessError(f"MuJoCo did not come to rest in {max_steps} steps")

    def position(self) -> np.ndarray:
        """The target's position (m), base frame."""
        self._mj.mj_kinematics(self.m, self.d)
        return self.d.site_xpos[self._site].copy()


@dataclass
class TrackRun:
    """One run along the path: ``errors`` (ticks, 3) of the target from the unloaded program's
    position (m), ``times`` (ticks,) (s)."""

    errors: np.ndarray
    times: np.ndarray

    def summary(self) -> dict[str, float]:
        """``max_error_m``, ``rms_error_m`` of the error's norm along the path."""
        norm = np.linalg.norm(self.errors, axis=1)
        return {"max_error_m": float(norm.max()), "rms_error_m": float(np.sqrt(np.mean(norm ** 2)))}


@dataclass
class Tracking:
    """A path tracked raw and compensated in MuJoCo (:func:`track`)."""

    robot: str
    points: int
    raw: TrackRun
    compensated: TrackRun
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """What ``stiffness track --json`` prints: ``raw`` and ``compensated`` (each
        ``max_error_m``, ``rms_error_m``), ``robot``, ``points``, ``ticks``, the settings and
        ``units``."""
        raw, comp = self.raw.summary(), self.compensated.summary()
        return {"robot": self.robot, "points": self.points, "ticks": int(self.raw.times.size),
                "raw": raw, "compensated": comp,
                "max_reduction_factor": raw["max_error_m"] / max(comp["max_error_m"], 1e-300),
                **self.settings,
                "units": {"error": "m", "time": "s", "wrench": "N, N.m"}}

    def plot(self, path: str | os.PathLike) -> Path:
        """Draw both errors along the path (log scale) into the PNG ``path``."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3.5))
        for run, label in ((self.raw, "raw path"), (self.compensated, "compensated")):
            ax.semilogy(run.times, np.maximum(np.linalg.norm(run.errors, axis=1), 1e-12),
                        label=label)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("target error (m)")
        ax.set_title(f"{self.robot} in MuJoCo: {self.points} points")
        ax.legend()
        fig.subplots_adjust(left=0.14, bottom=0.15, right=0.97, top=0.9)
        try:
            return atomic_write_with(path, lambda f: fig.savefig(f, format="png", dpi=120))
        finally:
            plt.close(fig)


def track(model: ElasticModel | Robot | str | Path, path: np.ndarray | str | Path,
          wrench: np.ndarray | list[float] | None = None, k_theta: np.ndarray | None = None,
          deg: bool = False, segment_time: float = 1.0, settle_time: float = 0.5,
          timestep: float = TIMESTEP, compensator_model: ElasticModel | None = None
          ) -> Tracking:
    """Track a joint path in MuJoCo, raw and compensated (see the module docstring).

    Parameters
    ----------
    model
        The elastic model MuJoCo simulates (a model file's path, an :class:`ElasticModel`,
        or a robot with ``k_theta``): linear joint springs, with the weight when it has a
        ``gravity_preload``.
    path
        (m, n) coordinates (rad, m) or a ``PATH.csv`` (``deg``: its angles in degrees; its
        per-row loads when ``wrench`` is None).
    wrench
        Dead wrench (3,) or (6,) (N, N.m, base axes) at the target, or (m, 6) one per point
        (blended along each segment as the coordinates are).
    segment_time
        Time (s) from one path point to the next.
    settle_time
        Time (s) at the first point before the path (not in the errors).
    timestep
        MuJoCo's step (s): one controller tick.
    compensator_model
        The model whose compensator commands the compensated run (default ``model``).

    Raises
    ------
    StiffnessError
        A model MuJoCo cannot simulate, a path beyond the joint limits or moving a rigid
        (welded) coordinate, bad times, a compensation that fails.
    """
    for name, value, needed in (("segment_time", segment_time, "a time >= 0 (s)"),
                                ("settle_time", settle_time, "a time >= 0 (s)"),
                                ("timestep", timestep, "a time > 0 (s)")):
        seconds = float(float_array(value, name, needed, ndim=0))
        if seconds < 0 or (name == "timestep" and seconds == 0):
            raise wrong_argument(name, value, needed)
    em = load_model(model, k_theta)
    gravity = exported_robot(em)[1]  # refuses what MuJoCo cannot simulate, before the path
    _, coords, loads = path_and_wrench(em.robot, path, wrench, deg)
    check_path_limits(em, coords)  # MuJoCo's ranges would stop it: metres of 'error'
    w = point_wrenches(loads, coords.shape[0])
    if coords.shape[0] > 1 and segment_time < timestep:  # 0 s: jumps, tracked by nothing
        raise StiffnessError(f"the segment time {segment_time:g} s is shorter than the time "
                             f"step {timestep:g} s: the path would jump from point to point; "
                             "give a segment time of many time steps (--segment-time)")
    rigid = np.setdiff1d(np.arange(em.robot.n_coordinates), em.robot.compliant_in_springs) \
        if em.robot.spring_joints == em.robot.coordinate_joints else np.array([], dtype=int)
    moved = [em.robot.coordinate_joints[j] for j in rigid
             if np.ptp(coords[:, j]) > 1e-12]
    if moved:
        raise StiffnessError(f"the path moves {', '.join(moved)}, which the model holds rigid "
                             "and MuJoCo welds: keep them constant or give them springs "
                             "(--compliant-joints with --kq)")
    times, targets, loads_t = _schedule(coords, w, segment_time, timestep)
    robot = em.robot
    data = robot.model.createData()
    nominal = np.empty((len(targets), 3))
    for i, c in enumerate(targets):
        pin.framesForwardKinematics(robot.model, data, robot.configuration(c))
        nominal[i] = data.oMf[robot.target_frame_id].translation
    comp = (compensator_model or em).compensator()
    runs = []
    for compensated in (False, True):
        arm = MujocoArm(em, coords[0], timestep)
        command = comp.command(coords[0], w[0]) if compensated else coords[0]
        arm.reset(command)
        for _ in range(int(round(settle_time / timestep))):
            arm.step(w[0])
        errors = np.empty((len(targets), 3))
        out = np.empty(robot.n_coordinates)
        for i, (c, load) in enumerate(zip(targets, loads_t, strict=True)):
            arm.command(comp.command(c, load, out=out) if compensated else c)
            errors[i] = arm.position() - nominal[i]  # the state the step's forces act at
            arm.step(load)
        runs.append(TrackRun(errors, times))
    settings = {"segment_time_s": segment_time, "settle_time_s": settle_time,
                "timestep_s": timestep, "gravity": gravity,
                "model": em.describe(),
                "compensator_model": (compensator_model or em).describe()}
    return Tracking(robot.title, coords.shape[0], runs[0], runs[1], settings)


def _schedule(coords: np.ndarray, wrenches: np.ndarray, segment_time: float, timestep: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (s), coordinates and wrenches of each tick along the path: each segment blended
    by ``(1 - cos(pi s)) / 2`` over ``segment_time``; the last point held one segment (at
    least one tick)."""
    per = max(1, int(round(segment_time / timestep)))
    s = (1.0 - np.cos(np.pi * np.arange(1, per + 1) / per)) / 2.0
    rows_c, rows_w = [], []
    for a in range(coords.shape[0] - 1):
        rows_c.append(coords[a] + s[:, None] * (coords[a + 1] - coords[a]))
        rows_w.append(wrenches[a] + s[:, None] * (wrenches[a + 1] - wrenches[a]))
    rows_c.append(np.repeat(coords[-1:], per, axis=0))
    rows_w.append(np.repeat(wrenches[-1:], per, axis=0))
    targets, loads = np.vstack(rows_c), np.vstack(rows_w)
    return np.arange(1, len(targets) + 1) * timestep, targets, loads
