"""A complementary stiffness that is round-off has no critical load.

A SCARA (vertical revolute axes, a vertical prismatic joint) under a vertical load: the load's
work -F.x depends on the prismatic coordinate alone, linearly, so its Hessian K_C is exactly
zero and no load along it buckles the arm. Pinocchio's K_C came out with entries of 1e-31
N.m/rad, and `kx` printed "stable under this load: K_theta - K_C is positive definite up to
1.367e+34 times it" instead of "at any magnitude", and K_C's class as ID.
"""

from __future__ import annotations

import json

import numpy as np

from stiffness.cli.main import main

SCARA = """name = "scara-dh"
[dh]
convention = "modified"
length_unit = "mm"
angle_unit = "deg"
joints = [
  { name = "j1", type = "revolute", alpha = 0, a = 0, theta = 0, d = 400 },
  { name = "j2", type = "revolute", alpha = 0, a = 350, theta = 0, d = 0 },
  { name = "j3", type = "prismatic", alpha = 180, a = 300, theta = 0, d = 0 },
  { name = "j4", type = "revolute", alpha = 0, a = 0, theta = 0, d = 0 },
]
tool = { xyz = [50.0, 0.0, 100.0], rpy = [0.0, 0.0, 0.0] }
"""


def _kx(tmp_path, capsys, wrench: str) -> dict:
    (tmp_path / "robot.toml").write_text(SCARA)
    code = main(["kx", "--robot", str(tmp_path / "robot.toml"), "--q", "0.1,0.8,0.05,0",
                 "--kq", "2e4,1e4,5e5,2e3", "--wrench", wrench, "--json"])
    assert code == 0
    return json.loads(capsys.readouterr().out)


def test_a_vertical_load_on_a_scara_never_buckles_it(tmp_path, capsys):
    out = _kx(tmp_path, capsys, "0,0,-80")
    assert np.abs(np.array(out["K_C"])).max() < 1e-20  # zero but for round-off
    assert out["critical_load_factor"] is None and out["stable"]
    assert out["definiteness"]["K_C"] == "PSD"  # a zero matrix's class (was ID, from the 1e-31)


def test_a_horizontal_load_keeps_its_finite_factor(tmp_path, capsys):
    """A horizontal force does load the revolute joints' geometry: K_C is O(F L) and its
    critical factor is 1 / the largest eigenvalue of K_theta^-1/2 K_C K_theta^-1/2."""
    out = _kx(tmp_path, capsys, "-80,0,0")  # pushing the tool towards the base
    k_c = np.array(out["K_C"])
    assert np.abs(k_c).max() > 1.0
    w = 1.0 / np.sqrt([2e4, 1e4, 5e5, 2e3])
    top = np.linalg.eigvalsh(0.5 * (k_c + k_c.T) * w[:, None] * w[None, :])[-1]
    assert top > 0 and abs(out["critical_load_factor"] * top - 1.0) < 1e-9


def test_round_off_entries_of_k_c_are_reported_as_zero(tmp_path, capsys):
    """At this pose Pinocchio's K_C under the vertical load had an entry of 2.3e-16 N.m/rad
    (printed as a number by `kx`); the load does no work on the geometry of the revolute
    joints (docstring above), so K_C is exactly zero, in the JSON and in the printed matrix."""
    (tmp_path / "robot.toml").write_text(SCARA)
    args = ["kx", "--robot", str(tmp_path / "robot.toml"), "--q", "0.3,0.2,0.05,0.5",
            "--kq", "2e4,1e4,5e5,2e3", "--wrench", "0,0,-80", "--quiet"]
    assert main(args + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert np.array(out["K_C"]).tolist() == np.zeros((4, 4)).tolist()
    # 1e-12 of the load's size: 80 N times the reach, about 1.2 m (base to tool, stretched)
    assert 1e-12 * 80 * 0.5 < out["K_C_round_off"] < 1e-12 * 80 * 2.0
    assert main(args) == 0
    text = capsys.readouterr().out
    block = text.split("K_C (N.m/rad")[1].split("K_X")[0]
    assert "e-" not in block.split("\n", 1)[1] and "0." in block
