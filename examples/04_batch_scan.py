"""Many configurations at once: batched kinematics and definiteness, then a workspace scan.

Run: ``python examples/04_batch_scan.py``. For the SK120 (a closed loop) over a grid of its
shoulder and elbow angles: :func:`stiffness.close_loops` closes the loop at every grid point,
:func:`stiffness.batch_kinematics` computes the Jacobians and the unit-wrench K_C basis in one
pass, and :func:`stiffness.definiteness_map` classifies K_C and K_theta - K_C for each load
(the analysis behind A&S Table IV). One grid point is checked against the one-at-a-time
:func:`stiffness.target_state`. :func:`stiffness.run_scan` does the same in chunks written to
disk (resumable; Dask for large sweeps; ``stiffness scan`` is its command line).
SI units: m, N, rad.
"""

import tempfile
from collections import Counter

import numpy as np

import stiffness
from stiffness.batch.linalg import class_names

robot = stiffness.load_robot("sk120")
k_theta = np.asarray(stiffness.default_stiffness(robot))             # N.m/rad
base = stiffness.default_coordinates(robot)                            # rad
q2, q3 = np.meshgrid(np.deg2rad(np.arange(-60, 61, 20)), np.deg2rad(np.arange(-100, 31, 20)))
coords = np.repeat(base[None], q2.size, axis=0)
coords[:, 1], coords[:, 2] = q2.ravel(), q3.ravel()
loads = np.array([[0.0, 0.0, -1000.0], [1000.0, 1000.0, 1000.0]])   # N, base axes

closed = stiffness.close_loops(robot, coords)
kin = stiffness.batch_kinematics(robot, closed.q[closed.closed])
maps = stiffness.definiteness_map(kin, loads, k_theta)
print(f"{closed.closed.sum()} of {len(coords)} grid points closed ({closed.n_closures} closures)")
for i, load in enumerate(loads):
    counts = Counter(class_names(maps.k_c_class[:, i]).tolist())
    print(f"load {load} N: K_C classes {dict(sorted(counts.items()))}; K_theta - K_C stays PD "
          f"up to {np.nanmin(maps.critical_factor[:, i]):.0f} x this load")

one = stiffness.target_state(robot, kin.q[0], load=loads[0])
k_c_batch = np.einsum("k,kab->ab", loads[0], kin.k_c_basis[0, :3])
print(f"grid point 0: batched K_C equals the single-pose one to "
      f"{np.abs(k_c_batch - one.k_c).max() / np.abs(one.k_c).max():.1e}")

axes = [{"index": i, "joint": robot.coordinate_joints[i], "lower": lo, "upper": hi, "step": st}
        for i, (lo, hi, st) in ((1, (-1.0, 1.0, 0.25)), (2, (-1.8, 0.5, 0.25)))]
spec = stiffness.ScanSpec(robot={"source": "sk120"}, preset="grid",
                          coordinate_joints=list(robot.coordinate_joints), base=base.tolist(),
                          axes=axes, samples=None, seed=0, loads=loads.tolist(),
                          load_names=["down", "diagonal"], k_theta=k_theta.tolist(),
                          map_axes=[0, 1])
with tempfile.TemporaryDirectory() as out:
    summary = stiffness.run_scan(spec, out, plots=False)
    scan = stiffness.load_scan(out)
print(f"scan: {summary['configurations']} configurations in {summary['chunks']['total']} "
      f"chunk(s); arrays {sorted(scan)[:4]} ...")
