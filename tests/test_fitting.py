"""The fitting engine (stiffness.calibration.fitting): parameters the data do not see, fits in
forked workers."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from stiffness import cores
from stiffness.calibration import fitting
from stiffness.calibration.fitting import NOMINAL_STIFFNESS, FitJob, fit_model, fit_models
from stiffness.cores import fork_workers, usable_cores
from stiffness.elastic.effects import make_effect
from stiffness.elastic.effects.geometry import Geometry, References
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.robot.robot import load_robot

K_TRUE = np.array([3e5, 3e5, 2e5, 4e4, 4e4, 4e4])
NOISE = 5e-6


def _campaign_model(compliant: tuple[str, ...]):
    """A UR5 model over tool0 (the wrist-3 axis passes through it: that stiffness is unseen)
    with a backlash on the shoulder, and noisy deflections of the six-joint truth."""
    robot = load_robot("ur5")
    geo = Geometry.of(robot)
    rng = np.random.default_rng(11)
    coords = np.repeat(rng.uniform(-1.5, 1.5, (20, 6)), 4, axis=0)
    forces = rng.normal(size=(80, 3)) * 100.0
    rows = geo.rows(coords, forces)
    refs = References.of(geo, rows, 1e5, np.full((1, 3), 1e-3))
    backlash = make_effect("backlash", "shoulder_lift_joint", geo)
    truth = Hypothesis(geo, rows, "enhanced", tuple(robot.compliant_joints), (backlash,), refs)
    measured = truth.predict(np.concatenate([np.log(K_TRUE), [2.0]]))
    measured = measured + rng.normal(size=measured.shape) * NOISE
    return Hypothesis(geo, rows, "enhanced", compliant, (backlash,), refs), measured


def test_an_unseen_stiffness_is_held_and_the_others_fit_as_without_it():
    robot = load_robot("ur5")
    joints = tuple(robot.compliant_joints)
    model, measured = _campaign_model(joints)
    x0 = np.concatenate([np.log(K_TRUE * 1.3), [0.5]])
    fit = fit_model(model, measured, NOISE, x0, x_scale=1.0)
    # wrist_3_joint: held at the nominal stiffness (ur5 declares none: 1e5 SI), not its start
    assert fit.x[5] == np.log(NOMINAL_STIFFNESS) != x0[5]
    assert fit.identifiability.dropped_at(5).reason == "no effect"
    # the same fit with that joint rigid (an independent model without it)
    five, _ = _campaign_model(joints[:5])
    reduced = fit_model(five, measured, NOISE, np.delete(x0, 5), x_scale=1.0)
    np.testing.assert_allclose(fit.cost, reduced.cost, rtol=1e-9)
    np.testing.assert_allclose(np.delete(fit.x, 5), reduced.x, rtol=1e-6)
    # and the solver does not crawl along the unseen direction
    assert fit.nfev <= 60
    assert fit.cost < 1.5 * measured.size  # it fits to noise


def test_an_objective_evaluates_each_recent_point_once(monkeypatch):
    """An Objective keeps the model's prediction and Jacobian at its last few points and the
    forward-difference Jacobian at its last one: going back to a point (a fit's start, judged
    for identifiability and then solved from) costs no evaluation, and gives bit for bit what
    a fresh Objective computes there."""
    base, measured = _campaign_model(tuple(load_robot("ur5").compliant_joints))
    model = base.extended(make_effect("frame_misalignment", None, base.geometry))
    numeric = int(np.sum(~model.analytic_columns))
    assert numeric > 0  # the forward differences are taken in some columns
    x0 = np.concatenate([np.log(K_TRUE), [2.0], np.full(model.n_params - 7, 1e-3)])
    points = [x0 + 0.01 * i for i in range(3)]
    fresh = fitting.Objective(model, measured, NOISE)
    expected = [(fresh.fun(x), fitting.Objective(model, measured, NOISE).jac(x))
                for x in points]
    calls = {"jacobian": 0, "predict": 0}

    def counted(name):
        original = getattr(Hypothesis, name)

        def call(self, x, *args, **kwargs):
            calls["jacobian" if name == "predict_with_jacobian" else "predict"] += 1
            return original(self, x, *args, **kwargs)
        return call

    monkeypatch.setattr(Hypothesis, "predict_with_jacobian", counted("predict_with_jacobian"))
    monkeypatch.setattr(Hypothesis, "predict", counted("predict"))
    objective = fitting.Objective(model, measured, NOISE)
    start = objective.columns(points[0], False)
    got = [(objective.fun(x), objective.jac(x)) for x in points]
    got[0] = (objective.fun(points[0]), objective.jac(points[0]))  # back at the start
    # the start's forward differences once for columns and jac, again when back at it
    assert calls == {"jacobian": 3, "predict": 4 * numeric}
    for (r, j), (r_ref, j_ref) in zip(got, expected, strict=True):
        np.testing.assert_array_equal(r, r_ref)
        np.testing.assert_array_equal(j, j_ref)
    np.testing.assert_array_equal(start[:, 6:], expected[0][1][:, 6:])


def _jobs() -> list[FitJob]:
    model, measured = _campaign_model(tuple(load_robot("ur5").compliant_joints))
    rng = np.random.default_rng(3)
    return [FitJob(model, measured, NOISE,
                   np.concatenate([np.log(K_TRUE * rng.uniform(0.5, 2.0, 6)), [0.5]]),
                   {"x_scale": 1.0, "tolerance": 1e-8}) for _ in range(5)]


def test_forked_fits_are_the_fits_of_this_process(monkeypatch):
    jobs = _jobs()
    serial = [job.run() for job in jobs]
    pools = []

    class CountedPool(cores.ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            pools.append(self)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(cores, "ProcessPoolExecutor", CountedPool)
    monkeypatch.setattr(fitting, "FORK_WORTH_S", 0.0)
    monkeypatch.setattr(cores, "fork_workers", lambda requested, tasks: min(2, tasks))
    forked = fit_models(jobs, workers=2)
    assert len(pools) == 1  # the four jobs after the first went to two forked workers
    for a, b, job in zip(serial, forked, jobs, strict=True):
        assert b.model is job.model
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.predicted, b.predicted)
        assert a.rss == b.rss and a.nfev == b.nfev


def test_fork_workers_rules():
    assert fork_workers(1, 10) == 1 and fork_workers(5, 0) == 1
    # in a fresh interpreter, which runs no other Python thread (a test process may: another
    # test's server or writer thread)
    fresh = subprocess.run([sys.executable, "-c", "from stiffness.cores import fork_workers; "
                            "print(fork_workers(4, 3))"], capture_output=True, text=True,
                           check=True)
    assert int(fresh.stdout) == (3 if sys.platform.startswith("linux") else 1)
    assert 1 <= fork_workers(None, 100) <= usable_cores()
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:  # a process running another Python thread never forks
        assert fork_workers(4, 10) == 1
    finally:
        release.set()
        other.join()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to list child processes")
def test_forked_workers_exit_when_their_command_is_killed():
    script = (
        "import os, time\n"
        "from stiffness.calibration import fitting\n"
        "parent = os.getpid()\n"
        "class Slow(fitting.FitJob):\n"
        "    def __init__(self):\n"
        "        pass\n"
        "    def run(self):\n"
        "        if os.getpid() != parent:\n"
        "            time.sleep(120)\n"
        "fitting.FORK_WORTH_S = 0.0\n"
        "fitting.fit_models([Slow() for _ in range(5)], workers=2)\n")
    command = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 60
        # the pool forks its workers one after the other: wait for both
        while len(workers := _children(command.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(workers) == 2
    finally:
        command.send_signal(signal.SIGKILL)
        command.wait(10)
    deadline = time.monotonic() + 10
    while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(Path(f"/proc/{pid}").exists() for pid in workers)


def _children(pid: int) -> list[int]:
    out = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines()
                          if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid):
            out.append(int(status.parent.name))
    return out
