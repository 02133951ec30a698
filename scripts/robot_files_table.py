"""Run ``stiffness kx`` on every URDF under some folders and check J and K_C by finite differences.

Produces the table of docs/robot-files.md ("Robots people already have")::

    python scripts/robot_files_table.py /tmp/gepetto/robots /tmp/pybullet_data \\
        --exclude random_urdfs --out table.md

Per URDF (its loop sidecar found as ``load_robot`` finds it): whether it loads unchanged (or
only with ``--fixed-base``), the coordinates, passive joints and idle passive motions, whether
the assembly search was needed, ``kx``'s exit code at the reference pose (zero, or the assembly
found near it; 1 N.m/rad per compliant joint... see ``--kq``), and the largest relative error of
J and K_C against central finite differences over the coordinates (loops closed by continuation
from the reference assembly). Files without any moving joint are listed as such.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from stiffness.cli.main import main as cli_main
from stiffness.errors import FloatingBaseError, StiffnessError
from stiffness.mechanics.formulation import target_state
from stiffness.robot.robot import Robot, load_robot

#: Dead force at the target (N) for kx and the K_C check.
FORCE_N = np.array([10.0, -20.0, 30.0])
#: Central-difference step over the coordinates (rad or m).
STEP = 1e-5


def _fd_errors(robot: Robot, q0: np.ndarray) -> tuple[float, float]:
    """Largest relative errors of J (position rows) and K_C against central differences."""
    coords = robot.coordinates_of(q0)
    state = target_state(robot, q0, FORCE_N)
    j_cols, kc_cols = [], []
    for i in robot.compliant_in_coordinates:
        values = []
        for sign in (1.0, -1.0):
            c = coords.copy()
            c[i] += sign * STEP
            s = target_state(robot, robot.configuration(c, seed=q0), FORCE_N)
            values.append((s.position, s.jacobian.T @ s.wrench))
        j_cols.append((values[0][0] - values[1][0]) / (2 * STEP))
        kc_cols.append((values[0][1] - values[1][1]) / (2 * STEP))
    fd_j, fd_kc = np.column_stack(j_cols), np.column_stack(kc_cols)
    err_j = np.abs(state.jacobian[:3] - fd_j).max() / max(np.abs(fd_j).max(), 1e-12)
    err_kc = np.abs(state.k_c - fd_kc).max() / max(np.abs(fd_kc).max(), 1e-9)
    return float(err_j), float(err_kc)


def _kx(path: Path, robot: Robot, fixed_base: bool) -> tuple[int, str]:
    """Exit code of ``stiffness kx`` at the reference pose, and its error line if any."""
    argv = ["kx", "--robot", str(path), "--kq", ",".join(["1e3"] * robot.n_compliant),
            "--wrench", ",".join(map(str, FORCE_N)), "--json"]
    if fixed_base:
        argv.append("--fixed-base")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = cli_main(argv)
    if code == 0:
        result = json.loads(out.getvalue())
        sub = result["K_X_subspace"]
        dims = "" if sub is None else f", {sub['rank']}-D"
        return code, dims
    return code, err.getvalue().strip().splitlines()[-1] if err.getvalue() else ""


def row(path: Path, root: Path) -> dict:
    """One table row for a URDF."""
    name = str(path.relative_to(root))
    started = time.perf_counter()
    out = {"robot": name, "loads": "", "coordinates": "", "passive": "", "idle": "",
           "search": "", "kx": "", "J": "", "K_C": ""}
    fixed = False
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            try:
                robot = load_robot(path)
            except FloatingBaseError:
                robot, fixed = load_robot(path, fixed_base=True), True
        except StiffnessError as exc:
            text = str(exc)
            out["loads"] = ("no moving joint" if "no joint of" in text
                            else f"refused: {text.split(': ', 1)[-1][:110]}")
            return {k: v.replace(f"{root}/", "") for k, v in out.items()}
    out["loads"] = ("with --fixed-base" if fixed else "yes") + (
        f" ({len(caught)} warnings)" if caught else "")
    out["coordinates"] = str(robot.n_coordinates)
    out["passive"] = str(len(robot.loop.passive_joints))
    try:
        assembly = robot.assemble(None)
        out["idle"] = str(assembly.idle_passive_motions)
        out["search"] = "yes" if assembly.assembly_search else "no"
        code, detail = _kx(path, robot, fixed)
        out["kx"] = f"{code}{detail}" if code == 0 else f"{code}: {detail[:110]}"
        if code == 0 and robot.n_compliant:
            try:
                err_j, err_kc = _fd_errors(robot, assembly.q)
                out["J"], out["K_C"] = f"{err_j:.1e}", f"{err_kc:.1e}"
            except StiffnessError as exc:
                out["J"] = out["K_C"] = "FD poses do not close"
                out["kx"] += f" (a pose {STEP:g} away does not close: {str(exc)[:80]})"
    except StiffnessError as exc:
        out["kx"] = f"2: {str(exc)[:110]}"
    out["seconds"] = f"{time.perf_counter() - started:.1f}"
    return {k: v.replace(f"{root}/", "") for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="folders searched for *.urdf")
    parser.add_argument("--exclude", action="append", default=[],
                        help="skip URDFs whose path contains this text (repeatable)")
    parser.add_argument("--out", type=Path, help="write the Markdown table here")
    parser.add_argument("--skip-static", action="store_true",
                        help="leave out files without any moving joint (objects)")
    args = parser.parse_args(argv)
    lines = ["| robot | loads unchanged? | coords | passive | idle | search | kx exit | "
             "J vs FD | K_C vs FD |", "|---|---|---|---|---|---|---|---|---|"]
    skipped = 0
    for folder in args.folders:
        for path in sorted(folder.rglob("*.urdf")):
            if any(text in str(path) for text in args.exclude):
                continue
            r = row(path, folder)
            if args.skip_static and r["loads"] == "no moving joint":
                skipped += 1
                continue
            line = (f"| {r['robot']} | {r['loads']} | {r['coordinates']} | {r['passive']} | "
                    f"{r['idle']} | {r['search']} | {r['kx']} | {r['J']} | {r['K_C']} |")
            lines.append(line.replace("\n", " "))
            print(line, file=sys.stderr, flush=True)
    text = "\n".join(lines) + "\n"
    if skipped:
        text += f"\n({skipped} files without any moving joint left out.)\n"
    if args.out:
        args.out.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
