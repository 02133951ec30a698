"""Cancel a UR5's deflection along a path, and choose its stiffest posture about the tool axis.

Run: ``python examples/05_compensate_ur5.py``. Every joint is a spring (N.m/rad); a 300 N
process force pushes on the tool. ``stiffness.compensate`` gives the joint commands whose
loaded equilibrium puts the tool on the unloaded path (exact), beside the usual first-order
Cartesian compensation (-C.F through inverse kinematics). ``stiffness.posture`` then turns the
tool about its axis, point by point, to the posture stiffest against a thrust along that axis.
SI units: m, N, rad. See docs/compensation.md.
"""

import numpy as np

import stiffness

k_theta = [3e5, 3e5, 2e5, 4e4, 4e4, 4e4]                               # N.m/rad
robot = stiffness.load_robot("ur5", frame="tool0")
model = stiffness.ElasticModel.joint_springs(robot, k_theta)
t = np.linspace(0.0, 1.0, 10)[:, None]
path = np.array([0.1, -1.2, 1.5, -0.3, 1.57, 0.2]) + t * [0.5, 0.3, -0.4, -0.2, 0.0, 0.0]
result = stiffness.compensate(model, path, wrench=[0.0, 0.0, -300.0])    # N, base axes
s = result.summary()
print(f"compensate: deflection up to {s['max_deflection_m'] * 1e3:.3f} mm; residual "
      f"{s['max_residual_m']:.1e} m exact, {s['max_residual_first_order_m']:.1e} m first-order")

# a spindle 0.1 m off the wrist axis, tool axis down, 300 N thrust along it
tool = stiffness.load_robot("ur5", frame="tool0", target_offset=[0.1, 0.0, 0.1])
positions = np.column_stack([np.full(10, 0.45), np.linspace(-0.2, 0.2, 10), np.full(10, 0.3)])
axes = np.tile([0.0, 0.0, -1.0], (10, 1))
chosen = stiffness.posture(tool, positions, axes=axes, wrench=[0.0, 0.0, 300.0],
                           k_theta=k_theta, steps=24, max_step_deg=20.0,
                           start=[0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
p = chosen.summary()
print(f"posture: max deflection {p['max_deflection_m'] * 1e3:.4f} mm vs "
      f"{p['max_deflection_fixed_m'] * 1e3:.4f} mm at a fixed angle (factor "
      f"{p['max_reduction_factor']:.3f}), joint steps up to {p['max_joint_step_deg']:.2f} deg")
