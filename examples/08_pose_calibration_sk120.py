"""Pose calibration of a robot with a closed loop, the Motoman SK120 (its parallelogram
five-bar closed at every pose): a tracker sees a marker on the fixture and one on the forearm
over 10 poses under a known payload of (400, 300, -2000) N, with the paper's three drive springs
and zero offsets of 0.1 and -0.05 deg on joint2 and joint3 hidden. One fit of those two
families (``stiffness diagnose --families joint_offsets,joint_compliance --max-steps 0``)
recovers each with its 95 % interval (docs/absolute-poses.md, *Closed loops*). SI units (m, N,
rad, N.m/rad); the robot file weighs nothing, so the payload alone loads the springs."""

import numpy as np

import stiffness

robot = stiffness.load_robot("sk120")
springs = np.array(robot.defaults["k_theta_SI"])                 # N.m/rad: joint1..joint3
offsets = {"joint2": np.deg2rad(0.1), "joint3": np.deg2rad(-0.05)}  # rad
markers = [stiffness.Marker("tip", "fixture_target", np.zeros(3)),    # declared offsets, m
           stiffness.Marker("fore", "forearm", np.array([0.3, 0.0, 0.1]))]
sim = stiffness.simulate_poses(
    robot, markers, poses=10, kq=springs, noise_std_m=20e-6, seed=0,
    payload=[400.0, 300.0, -2000.0],                                 # N, world axes
    effects=["frame=1,2,-3,500,300,100"]                             # the tracker (deg, mm)
    + [f"joint_offsets:{j}={np.rad2deg(v)}" for j, v in offsets.items()])  # effect text: deg
fit = stiffness.diagnose(sim.campaign, families=["joint_offsets", "joint_compliance"],
                         max_steps=0)
print(fit.verdict())
truth = {f"{j} compliance": 1.0 / k for j, k in zip(robot.compliant_joints, springs, strict=True)}
truth |= {f"{j} zero": v for j, v in offsets.items()}
found = {p.name: p for family in fit.named_parameters().values() for p in family}
for label, value in truth.items():
    p = found[label]
    print(f"{label}: true {value:.5g}, fitted {p.value:.5g} [{p.ci95[0]:.5g}, {p.ci95[1]:.5g}]"
          f" {p.unit}")
