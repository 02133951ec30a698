"""A wheel built from the checkout works outside it, with the checkout's numbers (issue 10, item 2).

The wheel is built from a copy of the checkout's build inputs (``pip wheel --no-deps
--no-build-isolation``: nothing is downloaded), installed with ``pip install --no-deps
--target`` into a temporary folder, and run through its own console script with only that
folder on ``PYTHONPATH``, from a folder outside the checkout. Its ``stiffness report``,
``stiffness kx --robot sk120 --json`` and ``stiffness check-jacobian --json`` must equal the
same commands run from the checkout (in this process), value for value; the file paths in
the outputs are the only difference allowed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from shared_run import run_folder

import stiffness
from stiffness.cli.main import main
from stiffness.robot.sources import robots_directory

ROOT = Path(__file__).resolve().parents[1]
#: What the build reads from the checkout.
BUILD_INPUTS = ("pyproject.toml", "README.md", "stiffness", "robots")
COMMANDS = {
    "kx": ["kx", "--robot", "sk120", "--json"],
    "check-jacobian": ["check-jacobian", "--json"],
}


def _run(cmd: list[str], env: dict, cwd: Path) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{done.stderr[-3000:]}"
    return done


def _build_and_run(folder: Path) -> None:
    """Build the wheel from a copy of the checkout's build inputs, install it into a folder of
    its own and run the commands from it, all under ``folder``; ``done`` marks the end.

    The three commands run at the same time (the suite's time budget).
    """
    src = folder / "src"
    for name in BUILD_INPUTS:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            src.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "--disable-pip-version-check", "-q", "-w", str(folder / "dist"), str(src)],
         dict(os.environ), src)
    (built,) = (folder / "dist").glob("stiffness-*.whl")
    _run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--no-compile",
          "--disable-pip-version-check", "-q", "--target", str(folder / "site"), str(built)],
         dict(os.environ), folder)
    installed = _installed(folder)
    installed["cwd"].mkdir()
    commands = {**COMMANDS, "report": ["report", "--out", str(installed["cwd"] / "report"),
                                       "--quiet"]}
    running = {name: subprocess.Popen([installed["script"], *args], env=installed["env"],
                                      cwd=installed["cwd"], stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True)
               for name, args in commands.items()}
    for name, process in running.items():
        stdout, stderr = process.communicate(timeout=600)
        assert process.returncode == 0, f"stiffness {name} failed:\n{stderr[-3000:]}"
        (folder / f"{name}.stdout").write_text(stdout)
    (folder / "done").touch()


def _installed(folder: Path) -> dict:
    """The environment, folders and console script of the wheel installed under ``folder``."""
    site = folder / "site"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STIFFNESS_ROBOTS")}
    env["PYTHONPATH"] = str(site)
    return {"env": env, "cwd": folder / "elsewhere", "site": site,
            "script": str(site / "bin" / "stiffness")}


@pytest.fixture(scope="session")
def wheel_run(tmp_path_factory, worker_id) -> Path:
    """The folder of :func:`_build_and_run`, made once per test run: the test workers share
    it (the first to need it builds it under a file lock, the others wait and read)."""
    with run_folder(tmp_path_factory, worker_id, "wheel-run") as root:
        folder = root / "wheel-run"
        if not (folder / "done").exists():
            shutil.rmtree(folder, ignore_errors=True)  # a worker that failed half-way
            _build_and_run(folder)
    return folder


@pytest.fixture
def wheel(wheel_run) -> Path:
    """The wheel built from the checkout."""
    (built,) = (wheel_run / "dist").glob("stiffness-*.whl")
    return built


@pytest.fixture
def installed(wheel_run) -> dict:
    """The wheel installed into a folder of its own; the environment and folder to run it in."""
    return _installed(wheel_run)


@pytest.fixture
def wheel_outputs(wheel_run) -> dict:
    """stdout of each command, and the report's folder, run from the installed wheel."""
    out = {name: (wheel_run / f"{name}.stdout").read_text() for name in COMMANDS}
    out["report"] = wheel_run / "elsewhere" / "report"
    return out


def _normalised(value, roots: list[str]):
    """JSON value with the robots folders and checkout paths replaced by placeholders."""
    if isinstance(value, dict):
        # run-dependent: the time taken and the provenance (date, command, commit, versions)
        return {k: _normalised(v, roots) for k, v in value.items()
                if k not in ("elapsed_s", "provenance")}
    if isinstance(value, list):
        return [_normalised(v, roots) for v in value]
    if isinstance(value, str):
        for root in roots:
            value = value.replace(root, "<robots>")
        return value
    return value


def _same(a: dict, b: dict, roots: list[str]) -> None:
    left = json.dumps(_normalised(a, roots), sort_keys=True)
    right = json.dumps(_normalised(b, roots), sort_keys=True)
    if left != right:
        diff = next(i for i, (x, y) in enumerate(zip(left, right, strict=False)) if x != y)
        raise AssertionError(f"outputs differ near: ...{left[max(0, diff - 120):diff + 80]}... "
                             f"vs ...{right[max(0, diff - 120):diff + 80]}...")


def _roots(installed) -> list[str]:
    return [str(installed["site"] / "stiffness" / "robots"), str(robots_directory())]


def test_the_wheel_holds_every_module_and_every_robot_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    package = {p.relative_to(ROOT).as_posix() for p in (ROOT / "stiffness").rglob("*.py")}
    robots = {"stiffness/robots/" + p.relative_to(ROOT / "robots").as_posix()
              for p in (ROOT / "robots").rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    missing = sorted((package | robots) - names)
    assert not missing, (f"the wheel lacks {missing[:10]}: list new subpackages in "
                         "pyproject.toml [tool.setuptools] packages")


def test_the_installed_copy_runs_from_its_own_files(installed):
    """Outside the checkout, the package and its robots come from the installed folder."""
    code = ("import json, stiffness, stiffness.robot.sources as r; print(stiffness.__file__); "
            "print(r.robots_directory()); print(json.dumps(r.shipped_robots()))")
    lines = _run([sys.executable, "-c", code], installed["env"],
                 installed["cwd"]).stdout.splitlines()
    site = str(installed["site"])
    assert lines[0].startswith(site) and lines[1].startswith(site), lines
    assert {"sk120", "hexapod", "griffis-duffy"} <= set(json.loads(lines[2]))


def test_version_is_the_package_metadata(installed):
    """``stiffness --version`` = ``stiffness.__version__`` = the wheel's metadata Version."""
    printed = _run([installed["script"], "--version"], installed["env"], installed["cwd"]).stdout
    assert printed.split() == ["stiffness", stiffness.__version__]
    (meta,) = installed["site"].glob("stiffness-*.dist-info/METADATA")
    assert f"Version: {stiffness.__version__}" in meta.read_text().splitlines()


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_commands_give_the_checkout_numbers(name, wheel_outputs, installed, capsys):
    capsys.readouterr()
    assert main(COMMANDS[name]) == 0
    here = json.loads(capsys.readouterr().out)
    _same(json.loads(wheel_outputs[name]), here, _roots(installed))


def test_report_gives_the_checkout_numbers(wheel_outputs, installed, sk120_report):
    theirs = wheel_outputs["report"]
    assert sorted(p.name for p in theirs.iterdir()) == sorted(p.name for p in
                                                              sk120_report.iterdir())
    _same(json.loads((theirs / "summary.json").read_text()),
          json.loads((sk120_report / "summary.json").read_text()), _roots(installed))


def _editable_checkout() -> Path | None:
    """The folder of an editable install of stiffness in this environment, if any.

    Every distribution named stiffness is looked at: the checkout's own ``stiffness.egg-info``
    (left by the editable build, found first from the checkout) has no ``direct_url.json``;
    the installed one in site-packages does.
    """
    from importlib import metadata

    for dist in metadata.distributions(name="stiffness"):
        info = json.loads(dist.read_text("direct_url.json") or "{}")
        if info.get("dir_info", {}).get("editable") and info["url"].startswith("file://"):
            return Path(info["url"][len("file://"):]).resolve()
    return None


@pytest.mark.skipif(_editable_checkout() != ROOT,
                    reason="needs an editable install of this checkout (pip install -e .)")
def test_editable_install_maps_the_robots_package_data():
    """``pip install -e .`` maps the package ``stiffness.robots`` onto the checkout's robots/."""
    from importlib import resources

    assert Path(str(resources.files("stiffness.robots"))).resolve() == ROOT / "robots"


def test_a_copy_without_its_robots_says_so(installed, tmp_path):
    """An installed copy that lost its package data fails with one line naming the fix."""
    site = tmp_path / "site"
    shutil.copytree(installed["site"] / "stiffness", site / "stiffness",
                    ignore=shutil.ignore_patterns("robots"))
    env = dict(installed["env"], PYTHONPATH=str(site))
    # an editable install of the checkout in this venv maps ``stiffness.robots`` onto the
    # checkout through a meta-path finder: drop it, as a venv without that install would be
    run_without_editable_finders = (
        "import sys; sys.meta_path[:] = [f for f in sys.meta_path "
        "if 'editable' not in getattr(f, '__module__', '').lower()]; "
        "from stiffness.cli.main import main; sys.exit(main(['kx', '--robot', 'sk120']))")
    done = subprocess.run([sys.executable, "-c", run_without_editable_finders],
                          env=env, cwd=installed["cwd"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "robots" in lines[0] and "pip install ." in lines[0], lines
