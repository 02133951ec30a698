"""The Motoman SK120 of Alici & Shirinzadeh (2005): a closed parallelogram loop under load.

Run: ``python examples/02_closed_loop_sk120.py``. The shipped ``sk120`` is a URDF tree plus a
loop file (``robots/sk120/sk120.loops.yaml``): its six coordinates are the printed joint
angles, and :meth:`Robot.configuration` solves the passive joints of the loop. Three joints
are springs (N.m/rad). K_C is linear in the load, so the load factor at which
K_theta - K_C stops being positive definite has a closed form: 1 / lambda_max of
K_theta^-1/2 K_C K_theta^-1/2. SI units: m, N, rad.
"""

import numpy as np

import stiffness

robot = stiffness.load_robot("sk120")
print(f"{robot.name}: coordinates {', '.join(robot.coordinate_joints)}; springs "
      f"{', '.join(robot.compliant_joints)}; loop passive joints "
      f"{', '.join(robot.loop.passive_joints)}")

q = robot.configuration(stiffness.default_coordinates(robot))   # Table II configuration A
k_theta = stiffness.joint_stiffness(stiffness.default_stiffness(robot), robot.n_compliant)
load, source = stiffness.default_load(robot, q, k_theta)          # N, base axes
print(f"load {load[:3]} N ({source})")

state = stiffness.target_state(robot, q, load=load[:3])
print(f"closed-loop J (3x{robot.n_compliant}, mm/rad):\n{np.round(state.jacobian[:3] * 1e3, 1)}")
for name, tangent in (("conventional", k_theta), ("enhanced", k_theta - state.k_c)):
    c_x = stiffness.compliance(state.jacobian[:3], tangent)
    print(f"{name:>12}: deflection {np.round(c_x @ load[:3] * 1e3, 4)} mm")

scale = np.diag(1.0 / np.sqrt(np.diag(k_theta)))
lam = np.linalg.eigvalsh(scale @ (0.5 * (state.k_c + state.k_c.T)) @ scale).max()
critical = 1.0 / lam
state_c = stiffness.target_state(robot, q, load=1.001 * critical * load[:3])
print(f"K_theta - K_C loses definiteness at {critical:.0f} x this load "
      f"({critical * np.linalg.norm(load[:3]) / 1e3:.0f} kN): just above it, "
      f"{stiffness.definiteness(k_theta - state_c.k_c)}")
