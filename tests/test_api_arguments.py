"""Wrong arguments to the Python API are refused where they enter, in one line naming the
argument, what was given and what it must be (:func:`stiffness.units.float_array`,
:func:`stiffness.units.whole_number`, :func:`stiffness.errors.wrong_argument`): a
:class:`~stiffness.errors.StiffnessError`, never NumPy's TypeError, ValueError or IndexError
(``model.at("0,0,0,0,0,0")`` said "could not convert string to float", ``identify(5)``
"expected str, bytes or os.PathLike object", ``compliance`` with a shape mismatch a gufunc
signature); valid arguments keep their results.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import stiffness
from stiffness.errors import StiffnessError
from stiffness.errors import given as given_text
from stiffness.robot.sources import robots_directory
from stiffness.units import float_array, whole_number

CHEAP = settings(max_examples=40, deadline=None)
NOT_FINITE = [math.nan, math.inf, -math.inf]
finite = st.floats(-10.0, 10.0, allow_nan=False)
TABLE2 = str(robots_directory() / "sk120" / "campaigns" / "table2")


def wrong_vector(sizes: tuple[int, ...]) -> st.SearchStrategy:
    """Anything that is not a vector of numbers of one of ``sizes``: strings, None, bools,
    dicts, other lengths, ragged nesting, strings among numbers, a NaN or infinity."""
    size = sizes[0]
    return st.one_of(
        st.text(max_size=12), st.none(), st.booleans(), st.dictionaries(st.text(), finite),
        st.lists(finite, max_size=9).filter(lambda v: len(v) not in sizes),
        st.lists(finite, min_size=size, max_size=size).flatmap(lambda v: st.sampled_from(
            [v[:-1] + [x] for x in NOT_FINITE] + [v[:-1] + ["1"], [v, [1.0]], [True] * size])))


def _one_line(exc: BaseException, name: str) -> str:
    message = str(exc)
    assert isinstance(exc, StiffnessError) and "\n" not in message, message
    assert message.startswith((name, "give ", "a load is", "q has", "need ")), message
    return message


@pytest.fixture(scope="module")
def model(ur5):
    return stiffness.load_model(ur5, k=[3e5, 3e5, 2e5, 4e4, 4e4, 4e4])


@CHEAP
@given(q=wrong_vector((6,)))
def test_model_at_refuses_wrong_coordinates(model, q):
    with pytest.raises(StiffnessError) as info:
        model.at(q)
    _one_line(info.value, "q")


@CHEAP
@given(wrench=wrong_vector((3, 6)).filter(lambda w: w is not None))
def test_model_at_refuses_wrong_loads(model, wrench):
    with pytest.raises(StiffnessError) as info:
        model.at(np.zeros(6), wrench)
    _one_line(info.value, "the load")


@CHEAP
@given(q=wrong_vector((6,)))
def test_target_state_refuses_wrong_coordinates(ur5, q):
    with pytest.raises(StiffnessError) as info:
        stiffness.target_state(ur5, q)
    _one_line(info.value, "q")


@CHEAP
@given(k=wrong_vector((6,)).filter(lambda k: k is not None and not isinstance(k, bool)))
def test_load_model_refuses_wrong_stiffnesses(ur5, k):
    with pytest.raises(StiffnessError) as info:
        stiffness.load_model(ur5, k=k)
    _one_line(info.value, "k_theta")


@CHEAP
@given(q=st.lists(finite, min_size=6, max_size=6),
       wrench=st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3))
def test_valid_arguments_keep_their_result(model, q, wrench):
    """A list, a tuple and an array of the same numbers give the same state; ints pass."""
    state = model.at(np.array(q), np.array(wrench))
    again = model.at(tuple(q), list(wrench))
    assert np.array_equal(state.q, again.q) and np.array_equal(state.wrench, again.wrench)
    assert np.array_equal(model.at([0] * 6, [0, 0, -10]).wrench, [0, 0, -10, 0, 0, 0])


@CHEAP
@given(rows=st.integers(1, 6), n=st.integers(1, 6), other=st.integers(1, 6),
       data=st.data())
def test_compliance_checks_its_matrices(rows, n, other, data):
    """J (r, n) and K (n, n) give J K^-1 J^T (checked against the inverse); any other shape,
    a string or a NaN is refused naming the argument."""
    jacobian = np.reshape(data.draw(st.lists(finite, min_size=rows * n, max_size=rows * n)),
                          (rows, n))
    k = np.diag(np.arange(1.0, n + 1.0))
    assert np.allclose(stiffness.compliance(jacobian, k),
                       jacobian @ np.linalg.inv(k) @ jacobian.T, atol=1e-12)
    if other != n:
        with pytest.raises(StiffnessError) as info:
            stiffness.compliance(jacobian, np.eye(other))
        assert _one_line(info.value, "tangent_stiffness").endswith(f"shape ({other}, {other})")
    bad = data.draw(st.sampled_from(["J", None, jacobian.ravel(), np.full((rows, n), np.nan)]))
    with pytest.raises(StiffnessError) as info:
        stiffness.compliance(bad, k)
    _one_line(info.value, "jacobian")
    with pytest.raises(StiffnessError) as info:
        stiffness.cartesian_stiffness(np.ones((rows, rows + 1)))
    _one_line(info.value, "compliance_matrix")


@pytest.mark.parametrize("call", [
    lambda: stiffness.identify(5), lambda: stiffness.identify(None),
    lambda: stiffness.diagnose(["campaign"]), lambda: stiffness.validate(5, "x"),
])
def test_workflows_refuse_a_campaign_or_model_of_another_type(call):
    with pytest.raises(StiffnessError) as info:
        call()
    assert _one_line(info.value, "").startswith(("campaign must be", "model must be"))


@pytest.mark.parametrize("kwargs, name", [
    ({"configs": "2"}, "configs"), ({"configs": 2.0}, "configs"), ({"repeats": True}, "repeats"),
    ({"kq": "3e5"}, "kq"), ({"max_force": "100"}, "max_force"),
])
def test_simulate_refuses_wrong_sizes_and_stiffnesses(kwargs, name):
    args = {"robot": "ur5", "kq": [3e5] * 6, "configs": 2, **kwargs}
    with pytest.raises(StiffnessError) as info:
        stiffness.simulate(**args)
    _one_line(info.value, name)


def test_design_and_scan_refuse_wrong_arguments(ur5):
    with pytest.raises(StiffnessError, match="^configs must be a whole number >= 1, got str"):
        stiffness.design(ur5, "2", 100.0, k=[3e5] * 6)
    with pytest.raises(StiffnessError, match=r"^q must be the 6 coordinates of ur5 \(rad, m\), "
                       r"got ndarray \[0.0, 0.0\]$"):
        stiffness.scan(ur5, k_theta=[3e5] * 6, q=np.zeros(2))
    with pytest.raises(StiffnessError, match="^wrench must be fx,fy,fz"):
        stiffness.scan(ur5, k_theta=[3e5] * 6, wrench="0,0,-10")


def test_the_helpers_name_what_was_given():
    assert given_text("0,0") == "str '0,0'" and given_text(np.zeros((2, 6))) == (
        "ndarray of shape (2, 6)")
    assert given_text("x" * 100).endswith("...") and len(given_text("x" * 100)) < 70
    with pytest.raises(StiffnessError, match=r"^v must be finite numbers: 2 numbers \(m\), "
                       r"got list \[1.0, nan\]$"):
        float_array([1.0, math.nan], "v", "2 numbers (m)", size=2)
    assert float_array((1, 2), "v", "2 numbers (m)", size=2).dtype == float
    assert whole_number(np.int64(3), "n") == 3
    for wrong in (0, 2.0, "2", True, None):
        with pytest.raises(StiffnessError, match="^n must be a whole number >= 1, got "):
            whole_number(wrong, "n")


@pytest.fixture(scope="module")
def path():
    """Three UR5 path points (rad)."""
    points = np.tile(np.deg2rad([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]), (3, 1))
    points[:, 0] = [0.0, 0.01, 0.02]
    return points


@pytest.mark.parametrize("call, name", [
    (lambda m, p: stiffness.compensate(m, p, wrench="0,0,-10"), "wrench"),
    (lambda m, p: stiffness.compensate(m, p, wrench=[[0, 0, -10]] * 2), "2 wrenches for 3"),
    (lambda m, p: stiffness.compensate(m, [["a"] * 6] * 3), "path"),
    (lambda m, p: stiffness.track(m, p, wrench="0,0,-10"), "wrench"),
    (lambda m, p: stiffness.posture(m, [["a", "b", "c"]], axes=[[0, 0, 1]]), "positions"),
    (lambda m, p: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes="z"), "axes"),
    (lambda m, p: stiffness.posture(m, [[0.4, 0.1, 0.4]], quaternions=[["1"] * 4]),
     "quaternions"),
    (lambda m, p: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes=[[0, 0, 1]], wrench=None),
     "give a process wrench"),
    (lambda m, p: stiffness.load_robot("ur5", target_offset="0,0,0.1"), "target_offset"),
    (lambda m, p: stiffness.simulate("ur5", kq=[3e5] * 6, configs=2, target_offset_m="0"),
     "target_offset_m"),
    (lambda m, p: stiffness.identify(TABLE2, starts="2"), "starts"),
    (lambda m, p: stiffness.scan(m.robot, k_theta=[3e5] * 6, samples="3"), "samples"),
])
def test_machining_and_robot_entries_refuse_wrong_arguments(model, path, call, name):
    """The path, wrench, positions, axes, offsets and counts of compensate, track, posture,
    load_robot, simulate, identify and scan: one line naming the argument (NumPy's 'could not
    convert string to float', "ufunc 'isfinite' not supported", 'must be real number'
    before)."""
    with pytest.raises(StiffnessError) as info:
        call(model, path)
    _one_line(info.value, name)


@pytest.mark.parametrize("call, name", [
    (lambda m: m.at(np.zeros(6)).compliance(rows="abc"), "rows"),
    (lambda m: m.at(np.zeros(6)).k_x(rows=5), "rows"),
    (lambda m: m.at(np.zeros(6)).compliance(rows=slice(6, 9)), "rows"),
    (lambda m: stiffness.load_robot("ur5", frame=5), "frame"),
    (lambda m: stiffness.load_robot("ur5", compliant_joints=5), "compliant_joints"),
    (lambda m: stiffness.load_robot("ur5", compliant_joints=[1, 2]), "compliant_joints"),
    (lambda m: stiffness.simulate("ur5", kq=[3e5] * 6, configs=2, seed="x"), "seed"),
    (lambda m: stiffness.simulate("ur5", kq=[3e5] * 6, configs=2, effects=[5]), "effects"),
    (lambda m: stiffness.simulate("ur5", kq=[3e5] * 6, configs=2,
                                  effects="backlash:elbow_joint=0.01"), "effects"),
    (lambda m: stiffness.deflection(m.at(np.zeros(6)).commanded, [3e5] * 6), "k_theta"),
    (lambda m: stiffness.deflection(m.at(np.zeros(6)).commanded, np.eye(5)), "k_theta"),
])
def test_state_robot_and_simulation_arguments(model, call, name):
    """``rows`` of a state's compliance and K_X (an IndexError before), the frame and
    compliant joints of load_robot (a Boost.Python signature, 'int' object is not iterable),
    simulate's seed and effects (a string was read letter by letter: "unknown effect 'b'"),
    deflection's joint stiffness matrix (a ufunc type error)."""
    with pytest.raises(StiffnessError) as info:
        call(model)
    _one_line(info.value, name)


@pytest.mark.parametrize("call, name", [
    (lambda m: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes=[[0, 0, 1]], wrench=[0, 0, -10],
                                 steps="3"), "steps"),
    (lambda m: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes=[[0, 0, 1]], wrench=[0, 0, -10],
                                 max_step_deg="3"), "max_step_deg"),
    (lambda m: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes=[[0, 0, 1]], wrench=[0, 0, -10],
                                 reference_angle_deg=math.nan), "reference_angle_deg"),
    (lambda m: stiffness.posture(m, [[0.4, 0.1, 0.4]], axes=[[0, 0, 1]], wrench=[0, 0, -10],
                                 start="x"), "start"),
    (lambda m: stiffness.design(m.robot, 2, 100.0, k=[3e5] * 6, noise_std_m="x"),
     "noise_std_m"),
    (lambda m: stiffness.design(m.robot, 2, 100.0, k=[3e5] * 6, candidates=4, seed="x"),
     "seed"),
    (lambda m: stiffness.identify(TABLE2, seed="x"), "seed"),
    (lambda m: stiffness.diagnose(TABLE2, seed=-1, max_steps=0), "seed"),
    (lambda m: stiffness.diagnose(TABLE2, workers="2", max_steps=0), "workers"),
    (lambda m: stiffness.scan(m.robot, k_theta=[3e5] * 6, samples=3, seed="x"), "seed"),
    (lambda m: stiffness.scan(m.robot, k_theta=[3e5] * 6, axes="q1"), "axes"),
    (lambda m: stiffness.scan(m.robot, k_theta=[3e5] * 6, axes={"q1": "0,1"}), "axes['q1']"),
])
def test_search_and_seed_arguments(model, call, name):
    """posture's search settings and start (TypeErrors of '<', isfinite, deg2rad before),
    design's noise, the seeds of design, identify, diagnose and scan (SeedSequence's
    TypeError, or ignored), diagnose's workers, scan's axes (an unpacking ValueError)."""
    with pytest.raises(StiffnessError) as info:
        call(model)
    _one_line(info.value, name)


@pytest.mark.parametrize("k", [[3e5] * 5, [3e5] * 5 + [-1.0], [3e5] * 5 + [math.nan], "3e5",
                               np.ones((2, 3)), np.ones((6, 6, 1))])
def test_joint_springs_are_checked_once(ur5, k):
    """load_model's k_theta, simulate's kq and design's k: one check
    (:func:`stiffness.mechanics.defaults.joint_stiffnesses`), one message (three before:
    'need one finite positive stiffness per compliant joint of ur5 ...', 'need 6 positive
    stiffnesses (one per compliant joint ...)' twice, worded apart)."""
    texts = set()
    for name, call in (("k_theta", lambda: stiffness.load_model(ur5, k=k)),
                       ("kq", lambda: stiffness.simulate(ur5, kq=k, configs=2)),
                       ("k", lambda: stiffness.design(ur5, 2, 100.0, k=k))):
        with pytest.raises(StiffnessError) as info:
            call()
        message = _one_line(info.value, name)
        assert message.startswith(f"{name} must be one finite positive stiffness per compliant "
                                  "joint of ur5 (shoulder_pan_joint, "), message
        texts.add(message.removeprefix(name))
    assert len(texts) == 1, texts


@pytest.mark.parametrize("args, kwargs, name", [
    (("0,0,0,0,0,0", np.diag([3e5] * 6), [0, 0, -10]), {}, "q"),
    ((np.zeros(6), "x", [0, 0, -10]), {}, "k_theta"),
    ((np.zeros(6), [3e5] * 6, [0, 0, -10]), {}, "k_theta"),
    ((np.zeros(6), np.eye(5), [0, 0, -10]), {}, "k_theta"),
    ((np.zeros(6), np.diag([3e5] * 6), [0, 0, -10]), {"max_iterations": "60"}, "max_iterations"),
])
def test_solve_equilibrium_checks_where_its_arguments_enter(ur5, args, kwargs, name):
    """A vector or a (5, 5) k_theta was a LinAlgError or a gufunc signature, a string 'x' a
    'could not convert string to float'; a valid call keeps its result."""
    with pytest.raises(StiffnessError) as info:
        stiffness.solve_equilibrium(ur5, *args, **kwargs)
    assert _one_line(info.value, name).startswith(f"{name} must be ")
    q = [0.0, -1.2, 1.4, -0.9, -1.5, 0.3]
    np.testing.assert_array_equal(
        stiffness.solve_equilibrium(ur5, q, np.diag([3e5] * 6), (0, 0, -50)).dtheta,
        stiffness.solve_equilibrium(ur5, np.array(q), np.diag([3e5] * 6),
                                    np.array([0.0, 0, -50, 0, 0, 0])).dtheta)


@pytest.mark.parametrize("call, name", [
    (lambda m, p: m.at(np.zeros(6), closed="x"), "closed"),
    (lambda m, p: m.at(np.zeros(6), closed=np.zeros(5)), "closed"),
    (lambda m, p: m.linear_deflection("0,0,0,0,0,0", [0, 0, -10]), "coords"),
    (lambda m, p: m.linear_deflection(np.zeros(5), [0, 0, -10]), "coords"),
    (lambda m, p: stiffness.track(m, p, [0, 0, -10], segment_time="1"), "segment_time"),
    (lambda m, p: stiffness.track(m, p, [0, 0, -10], settle_time=-1.0), "settle_time"),
    (lambda m, p: stiffness.track(m, p, [0, 0, -10], timestep=0.0), "timestep"),
    (lambda m, p: stiffness.track(m, p, [0, 0, -10], timestep=math.nan), "timestep"),
])
def test_state_and_tracking_arguments(model, path, call, name):
    """A state's closed configuration and linear_deflection's coordinates (NumPy's 'could not
    convert string to float' or Pinocchio's signature before), track's times (np.isfinite of
    a string was a TypeError)."""
    with pytest.raises(StiffnessError) as info:
        call(model, path)
    assert _one_line(info.value, name).startswith(f"{name} must be ")
