"""Identify joint stiffness from a force/deflection campaign (here a synthetic one).

Run: ``python examples/03_identify_campaign.py``. :func:`stiffness.simulate` writes what a rig
would: a ``campaign.toml`` (robot, target, units, noise) and ``measurements.csv`` (one row per
configuration and load: joint angles in deg, force in N, measured deflection in mm), from a
UR5 with known springs and 5 um noise. :func:`stiffness.load_campaign` reads it back (any
campaign in that format works, e.g. ``robots/sk120/campaigns/table2``) and
:func:`stiffness.identify` fits K_theta by nonlinear least squares (A&S eq. 11-13), with 95 %
intervals.
"""

import tempfile
from pathlib import Path

import numpy as np

import stiffness

TRUE_K = [2.0e5, 1.5e5, 8.0e4]  # N.m/rad
ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]

with tempfile.TemporaryDirectory() as tmp:
    sim = stiffness.simulate("ur5", kq=TRUE_K, compliant_joints=ARM, configs=8,
                             loads_per_config=3, max_force=300.0, noise_std_m=5e-6, seed=3)
    folder = sim.write(Path(tmp) / "ur5-campaign").parent
    print(f"campaign written: {sorted(p.name for p in folder.iterdir())}")
    campaign = stiffness.load_campaign(folder)
    result = stiffness.identify(campaign, starts=2)

print(f"{campaign.n_rows} measurements, RMS residual {result.rms_residual_m * 1e6:.2f} um")
for joint, k, lo, hi, true in zip(result.joints, result.k, result.ci95_low, result.ci95_high,
                                  TRUE_K, strict=True):
    inside = "inside" if lo <= true <= hi else "OUTSIDE"
    print(f"  {joint:>20}: {k:.4g} N.m/rad, 95 % [{lo:.4g}, {hi:.4g}] ({inside}: true {true:.4g})")
print(f"largest relative error {np.max(np.abs(result.k / TRUE_K - 1)):.2%}")
