"""The whole loop from Python: simulate a campaign hiding an effect, diagnose it, load the final
model and evaluate its Cartesian stiffness at a new pose.

Run: ``python examples/06_python_loop.py``. :func:`stiffness.simulate` measures a UR5 whose
arm joints are springs and whose forearm bends (a ``link_compliance`` the campaign does not
declare); :func:`stiffness.diagnose` finds the bend; :func:`stiffness.load_model` reads the
``final-model.json`` it writes (the same file ``stiffness diagnose --out`` writes) into an
:class:`stiffness.ElasticModel`. ``model.at(q, wrench)`` is the model at a pose and load: its
``.stiffness()`` is what ``stiffness kx --model final-model.json`` prints, and
``.equilibrium()`` the exact loaded pose. The true robot, built from the same effect through
its one hook (:meth:`stiffness.elastic.effects.base.Effect.contribute`), gives the reference.
SI units throughout.
"""

import tempfile
from pathlib import Path

import numpy as np

import stiffness
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
TRUE_K = [3e4, 2e4, 1.5e4]  # N.m/rad
BEND, K_BEND = "elbow_joint->wrist_1_joint", 5e4  # N.m/rad about both axes
NEW_POSE = [0.3, -1.1, 1.4, -0.6, 1.2, 0.4]  # rad, not one of the campaign's
LOAD = [40.0, -25.0, -90.0]  # N, base axes

sim = stiffness.simulate("ur5", kq=TRUE_K, compliant_joints=ARM, target_offset_m=[0, 0, 0.1],
                         effects=[f"link_compliance:{BEND}={K_BEND}"], configs=8,
                         noise_std_m=5e-6, seed=3)
diagnosis = stiffness.diagnose(sim.campaign, max_steps=2, propose=False, workers=1)
print(f"diagnosis: {diagnosis.final.model.describe()}")
with tempfile.TemporaryDirectory() as tmp:
    written = diagnosis.write(Path(tmp) / "diagnosis")
    model = stiffness.load_model(written["final_model"])
state = model.at(NEW_POSE, LOAD)
k_x = state.stiffness()  # N/m, enhanced formulation, base axes: what `stiffness kx` prints
print(f"K_X of the diagnosed model at the new pose (N/m):\n{np.array2string(k_x, precision=4)}")
print(f"stable: {state.stable} (critical load factor {state.critical_load_factor:.3g})")

robot = stiffness.load_robot("ur5", compliant_joints=ARM, target_offset=[0, 0, 0.1])
bend = make_effect("link_compliance", BEND, Geometry.of(robot))
truth = stiffness.ElasticModel.with_effects(robot, TRUE_K, [(bend, [K_BEND, K_BEND])])
true_state = truth.at(NEW_POSE, LOAD)
true_k_x = true_state.stiffness()
springs = stiffness.ElasticModel.joint_springs(robot, TRUE_K).at(NEW_POSE, LOAD).stiffness()
error = np.linalg.norm(k_x - true_k_x) / np.linalg.norm(true_k_x)
missed = np.linalg.norm(springs - true_k_x) / np.linalg.norm(true_k_x)
print(f"K_X within {100 * error:.2f}% of the true robot's (the springs alone: "
      f"{100 * missed:.1f}% off)")
exact = state.equilibrium().dx
linear = state.compliance() @ np.array(LOAD)
print(f"deflection under the load: exact {1e3 * np.linalg.norm(exact):.4f} mm, linear "
      f"{1e3 * np.linalg.norm(linear):.4f} mm")
