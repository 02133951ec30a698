"""Cartesian stiffness of a UR5 at one configuration, with and without the load term.

Run: ``python examples/01_kx_ur5.py``. The UR5 comes from example-robot-data; every joint is a
spring (N.m/rad). The enhanced stiffness (Alici & Shirinzadeh eq. 10) works through the
compliance C = J (K_theta - K_C)^-1 J^T, the conventional one (eq. 8) drops K_C. The linear
deflection is then compared with the exact elastostatic equilibrium under the same dead load.
SI units: m, N, rad.
"""

import numpy as np

import stiffness

robot = stiffness.load_robot("ur5", frame="tool0")
q = robot.configuration([0.0, -1.2, 1.5, -0.3, 1.57, 0.0])        # rad, one per joint
k_theta = stiffness.joint_stiffness([3e5, 3e5, 2e5, 4e4, 4e4, 4e4], robot.n_compliant)
load = np.array([0.0, 0.0, -200.0])                                # N at the tool, base axes

state = stiffness.target_state(robot, q, load=load)
print(f"target at {np.round(state.position, 4)} m; J is {state.jacobian.shape[0]}x"
      f"{state.jacobian.shape[1]}")
for name, tangent in (("conventional", k_theta), ("enhanced", k_theta - state.k_c)):
    c_x = stiffness.compliance(state.jacobian[:3], tangent)         # m/N
    k_x = stiffness.cartesian_stiffness(c_x)                        # N/m
    print(f"{name:>12}: principal stiffness {np.round(np.linalg.eigvalsh(k_x) / 1e3, 1)} kN/m, "
          f"{stiffness.definiteness(k_x)}")

linear = stiffness.deflection(state, k_theta, "enhanced")           # m
exact = stiffness.solve_equilibrium(robot, q, k_theta, load)        # Newton, loads held dead
gap = np.linalg.norm(linear - exact.dx) / np.linalg.norm(exact.dx)
print(f"deflection: linear {np.round(linear * 1e3, 4)} mm, exact {np.round(exact.dx * 1e3, 4)} "
      f"mm ({gap:.1e} apart: second order in the load)")
