"""Coverage of identify's 95 % stiffness intervals when the rotation noise is not declared:
the measurement behind docs/diagnose.md's table (Rotations) and
``deflection_noise.interval_quantiles``.

Usage::

    python scripts/rotation_noise_coverage.py --configs 2 --seeds 1500   # 2 poses x 2 loads
    python scripts/rotation_noise_coverage.py --configs 4 --seeds 1500   # 4 poses x 2 loads
    python scripts/rotation_noise_coverage.py --configs 2 --seeds 1500 --declared
    python scripts/rotation_noise_coverage.py --configs 2 --seeds 1500 --no-translation-noise

UR5, all six joints compliant (3e4, 2e4, 1.5e4, 5e3, 5e3, 4e3 N.m/rad), the target 7 cm off
wrist_3's axis, ``--configs`` poses x 2 loads up to 100 N, 5 um and 0.05 mrad noise, seeds
0 to ``--seeds`` - 1, the rotation noise not declared (``--declared``: declared;
``--no-translation-noise``: neither declared, a row for t with N - p added, the rule
until 6 December 2026 there); ``identify --starts 1``. Per joint, each seed's standardised
error of the compliance ``z = (c - c_true) / se_c = (1 - k / k_true) / se(ln k)`` (the
interval is the compliance's, ``c -+ q se_c``, carried to ``k``, so it covers when
``|z| <= q``) is read against three quantiles: the normal's, Student's t with
``nu_r = N_r - p N_r / N`` (the rotation residuals' degrees of freedom) and t with the
joint's reported ``ci95_dof`` (the Welch-Satterthwaite effective degrees of freedom,
``null`` for the normal's); beside them the reported intervals' own coverage (the last,
unless a bound cut one) and the binomial standard
error. One process; a few minutes per 1500 seeds.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from scipy.stats import norm
from scipy.stats import t as student

from stiffness.calibration.identify import identify
from stiffness.planning.simulate import simulate

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint"]
KQ = np.array([3e4, 2e4, 1.5e4, 5e3, 5e3, 4e3])


def one(seed: int, configs: int, declared: bool, translations: bool = True
        ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """One campaign's standardised errors, reported degrees of freedom (``inf``: normal),
    ``nu_r`` and whether each reported interval covers."""
    sim = simulate("ur5", kq=KQ, compliant_joints=JOINTS, max_force=100.0, noise_std_m=5e-6,
                   rotations=True, configs=configs, loads_per_config=2, seed=seed,
                   target_offset_m=[0.05, 0.0, 0.05])
    campaign = (sim.campaign if declared
                else dataclasses.replace(sim.campaign, rotation_noise_std_rad=None))
    if not translations:
        campaign = dataclasses.replace(campaign, noise_std_m=None)
    r = identify(campaign, starts=1)
    z = (1.0 - r.k / KQ) / np.sqrt(np.diag(r.covariance_log))
    dof = np.array([np.inf if v is None else v for v in (r.ci95_dof or (None,) * 6)])
    covered = (r.ci95_low <= KQ) & (r.ci95_high >= KQ)
    return z, dof, 0.5 * (r.n_residuals - r.n_parameters), covered


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", type=int, default=2)
    parser.add_argument("--seeds", type=int, default=1500)
    parser.add_argument("--declared", action="store_true")
    parser.add_argument("--no-translation-noise", action="store_true")
    args = parser.parse_args()
    runs = [one(s, args.configs, args.declared, not args.no_translation_noise)
            for s in range(args.seeds)]
    z = np.array([r[0] for r in runs])
    dof = np.array([r[1] for r in runs])
    nu_r = runs[0][2]
    quantiles = {"normal": norm.ppf(0.975), f"t(nu_r={nu_r:g})": student.ppf(0.975, nu_r),
                 "t(nu_eff)": student.ppf(0.975, dof)}
    if args.no_translation_noise:
        quantiles[f"t(N-p={2 * nu_r:g})"] = student.ppf(0.975, 2 * nu_r)
    print(f"{args.configs} poses x 2 loads, {args.seeds} seeds, rotation noise "
          f"{'declared' if args.declared else 'undeclared'}"
          f"{', translation noise undeclared' if args.no_translation_noise else ''}; "
          "coverage per joint "
          f"(binomial standard error), all six")
    print(f"{'':14}" + "".join(f"{j.removesuffix('_joint'):>16}" for j in JOINTS) + "    all six")
    rows = {name: np.abs(z) <= q for name, q in quantiles.items()}
    rows["reported"] = np.array([r[3] for r in runs])
    for name, hit in rows.items():
        cover = hit.mean(axis=0)
        se = np.sqrt(cover * (1.0 - cover) / hit.shape[0])
        print(f"{name:14}" + "".join(f"{c:>9.3f} ({s:.3f})" for c, s in zip(cover, se,
                                                                           strict=True))
              + f"{hit.mean():>11.3f}")
    print(f"{'median nu_eff':14}" + "".join(f"{v:>16.4g}" for v in np.median(dof, axis=0)))
    print(f"{'var z':14}" + "".join(f"{v:>16.3f}" for v in np.var(z, axis=0)))


if __name__ == "__main__":
    main()
