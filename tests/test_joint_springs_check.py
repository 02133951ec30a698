"""Joint springs are checked once (:func:`stiffness.mechanics.defaults.joint_stiffnesses`),
wherever they enter: the viewer's ``k_theta`` as ``load_model``'s, and the flag ``--kq`` of
``robot export`` as of ``kx`` (its numbers read as every flag's first). Before, the viewer
refused a NaN, a zero or a wrong count in ``mechanics.formulation``'s words, raised a bare
ValueError on a string (``"8e4 N.m/rad"``) and drew a coupled matrix as joint springs;
``robot export --kq`` had its own message and ``kx --kq -1,...`` named no flag."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import stiffness
from stiffness.cli.main import main
from stiffness.errors import StiffnessError
from stiffness.viewer import StiffnessViewer

KQ = [8e4, 8e4, 5e4, 2e4, 2e4, 2e4]
JOINTS = ("shoulder_pan_joint, shoulder_lift_joint, elbow_joint, wrist_1_joint, "
          "wrist_2_joint, wrist_3_joint")
NEEDED = f"one finite positive stiffness per compliant joint of ur5 ({JOINTS}), N.m/rad (N/m "


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text, text
    return text


BAD = {"nan": [math.nan, *KQ[1:]], "inf": [math.inf, *KQ[1:]], "negative": [-8e4, *KQ[1:]],
       "zero": [0.0, *KQ[1:]], "count": KQ[:5], "unit string": ["8e4 N.m/rad", *KQ[1:]],
       "string": "8e4,8e4,5e4,2e4,2e4,2e4", "matrix 5x5": np.eye(5)}


@pytest.mark.parametrize("name", list(BAD))
def test_viewer_refuses_bad_springs_as_load_model_does(ur5, name):
    """The viewer's message is load_model's, word for word after the argument's name."""
    k = BAD[name]
    with pytest.raises(StiffnessError) as viewer:
        StiffnessViewer(ur5, k)
    with pytest.raises(StiffnessError) as api:
        stiffness.load_model(ur5, k=k)
    text = _one_line(viewer.value)
    assert text.startswith(f"k_theta must be {NEEDED}prismatic): a vector or a diagonal matrix,"
                           " got "), text
    assert text == str(api.value)


def test_viewer_refuses_coupled_springs(ur5):
    """A matrix with off-diagonal terms is no set of joint springs (it was drawn as one)."""
    with pytest.raises(StiffnessError, match="couples joints") as info:
        StiffnessViewer(ur5, np.diag(KQ) + 1.0)
    _one_line(info.value)


finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(values=st.lists(finite, min_size=1, max_size=9))
def test_any_non_positive_or_miscounted_springs_are_refused(ur5, values):
    """For all lists of numbers but six positive ones: the viewer refuses them in one line
    naming ``k_theta`` and what it must be."""
    assume(len(values) != 6 or min(values) <= 0)
    with pytest.raises(StiffnessError) as info:
        StiffnessViewer(ur5, values)
    assert _one_line(info.value).startswith(f"k_theta must be {NEEDED}")


def test_viewer_keeps_valid_springs_as_their_diagonal(ur5):
    """A vector and its diagonal matrix give the same joint stiffness (N.m/rad)."""
    for k in (KQ, np.diag(KQ), tuple(KQ)):
        np.testing.assert_array_equal(StiffnessViewer(ur5, k).k_theta, np.diag(KQ))


FLAG_BAD = {"negative": ("-8e4,8e4,5e4,2e4,2e4,2e4", "[-80000.0, "),
            "zero": ("0,8e4,5e4,2e4,2e4,2e4", "[0.0, "),
            "count": ("8e4,8e4,5e4,2e4,2e4", "[80000.0, ")}


@pytest.mark.parametrize("command", ["robot", "kx"])
@pytest.mark.parametrize("name", list(FLAG_BAD))
def test_kq_flag_is_checked_once(capsys, tmp_path, command, name):
    """``robot export --kq`` and ``kx --kq``: the same one line, naming ``--kq``, the joints and
    the fix, and no file written."""
    text, shown = FLAG_BAD[name]
    argv = {"robot": ["robot", "export", "--mjcf", str(tmp_path / "out.xml")],
            "kx": ["kx", "--wrench", "0,0,-1"]}[command]
    assert main([*argv, "--robot", "ur5", f"--kq={text}"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    prefix = f"stiffness {command}{' export' if command == 'robot' else ''}: error: "
    assert line.startswith(f"{prefix}--kq must be {NEEDED}prismatic): comma-separated in their "
                           f"order, or choose the joints with --compliant-joints, got list "
                           f"{shown}"), line
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("text", "words"), [
    ("nan,8e4,5e4,2e4,2e4,2e4", "--kq values must be finite, got 'nan'"),
    ("inf,8e4,5e4,2e4,2e4,2e4", "--kq values must be finite, got 'inf'"),
    ("8e4N.m/rad,8e4,5e4,2e4,2e4,2e4", "--kq takes comma-separated numbers; '8e4N.m/rad' is "
                                       "not a number"),
    ("80kN.m/rad,8e4,5e4,2e4,2e4,2e4", "'80kN.m/rad' is not a number"),
])
def test_kq_numbers_are_read_as_every_flags(capsys, tmp_path, text, words):
    """A NaN, an infinity or a unit written into ``--kq`` (it is N.m/rad, N/m prismatic): the
    flag's number rule, one line."""
    out = tmp_path / "out.xml"
    assert main(["robot", "export", "--robot", "ur5", "--mjcf", str(out), f"--kq={text}"]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0], lines
    assert not out.exists()
