"""Workspace scans: K_C definiteness and the load at which K_theta - K_C loses definiteness.

K_C is linear in the load, so a scan computes, per configuration, K_C for the unit forces along
x, y, z once and combines them for every load case. The critical load factor of a direction
``F`` is ``1 / lambda_max(K_theta^-1/2 K_C(F) K_theta^-1/2)`` (when that eigenvalue is
positive): ``K_theta - s K_C(F)`` is positive definite exactly for ``s`` below it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stiffness.batch.linalg import class_names
from stiffness.mechanics.formulation import DEFINITENESS_CLASSES, definiteness, target_states
from stiffness.robot.robot import Robot
from stiffness.workspace.maps import DEFINITENESS_FIELDS, compute_maps
from stiffness.workspace.spec import ScanSpec


@dataclass
class DefinitenessScan:
    """Result of :func:`definiteness_scan`.

    Attributes
    ----------
    coordinates
        (m, n_coordinates) scanned coordinates (rad, m).
    loads
        (c, 3) load cases (N).
    classes
        (m, c) definiteness class of K_C per configuration and case.
    tangent_classes
        (m, c) definiteness class of K_theta - K_C.
    critical_factor
        (m, c) load multiplier at which K_theta - K_C stops being positive definite
        (inf where K_C has no positive direction).
    k_c_diagonal
        (m, 3, n) diagonal of K_C for the unit forces along x, y, z (N.m/rad per N).
    determinant_positive
        (m, c) whether det K_C > 0 (not a definiteness test: kept to audit tables that used it).
    """

    coordinates: np.ndarray
    loads: np.ndarray
    classes: np.ndarray
    tangent_classes: np.ndarray
    critical_factor: np.ndarray
    k_c_diagonal: np.ndarray
    determinant_positive: np.ndarray

    def counts(self, case: int) -> dict[str, int]:
        """Number of configurations in each definiteness class for a load case."""
        col = self.classes[:, case]
        return {c: int(np.sum(col == c)) for c in DEFINITENESS_CLASSES}


def definiteness_scan(
    robot: Robot,
    coordinates: np.ndarray,
    loads: np.ndarray,
    k_theta: np.ndarray,
    rtol: float = 1e-9,
    progress: Callable[[int, int], None] | None = None,
) -> DefinitenessScan:
    """Definiteness of K_C and of K_theta - K_C over configurations and load cases.

    Configurations are visited in the given order, each loop closure seeded from the previous
    one (order the grid so that neighbours follow each other).
    """
    coordinates = np.asarray(coordinates, dtype=float)
    loads = np.asarray(loads, dtype=float)
    m, c = coordinates.shape[0], loads.shape[0]
    classes = np.empty((m, c), dtype="<U3")
    tangent = np.empty((m, c), dtype="<U3")
    factor = np.full((m, c), np.inf)
    diag = np.empty((m, 3, robot.n_compliant))
    det_positive = np.zeros((m, c), dtype=bool)
    k_half_inv = np.diag(1.0 / np.sqrt(np.diag(k_theta)))
    q = None
    for i, coords in enumerate(coordinates):
        q = robot.configuration(coords, seed=q)
        units = [s.k_c for s in target_states(robot, q, np.eye(3))]
        diag[i] = [np.diag(u) for u in units]
        for j, load in enumerate(loads):
            k_c = sum(load[a] * units[a] for a in range(3))
            classes[i, j] = definiteness(k_c, rtol=rtol)
            det_positive[i, j] = np.linalg.det(k_c) > 0
            tangent[i, j] = definiteness(k_theta - k_c, rtol=rtol)
            top = np.linalg.eigvalsh(k_half_inv @ (0.5 * (k_c + k_c.T)) @ k_half_inv)[-1]
            if top > 0:
                factor[i, j] = 1.0 / top
        if progress is not None:
            progress(i + 1, m)
    return DefinitenessScan(coordinates, loads, classes, tangent, factor, diag, det_positive)


def terminal_progress(label: str, quiet: bool = False) -> Callable[[int, int], None] | None:
    """A progress callback drawing a bar on stderr, or None when quiet or not a TTY."""
    if quiet or not sys.stderr.isatty():
        return None

    def show(done: int, total: int) -> None:
        if done == total or done % max(1, total // 200) == 0:
            width = 30
            filled = int(width * done / total)
            sys.stderr.write(f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total}")
            if done == total:
                sys.stderr.write("\n")
            sys.stderr.flush()

    return show


def batched_definiteness_scan(
    robot: Robot,
    coordinates: np.ndarray,
    loads: np.ndarray,
    k_theta: np.ndarray,
    rtol: float = 1e-9,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = 8192,
) -> DefinitenessScan:
    """:func:`definiteness_scan` computed by the scan engine's chunk kernel
    (:func:`stiffness.workspace.maps.compute_maps`, the same code as ``stiffness scan``).

    Same result to round-off, two orders of magnitude faster: loop closures are shared between
    configurations with the same loop coordinates (:func:`stiffness.batch.kernels.close_loops`),
    the kinematics come from a tight Pinocchio loop and the eigenvalues from stacked LAPACK
    calls. Configurations whose loop cannot be closed get class "" and a NaN critical factor.

    Parameters
    ----------
    robot
        The robot.
    coordinates
        (m, n_coordinates) coordinates (rad, m).
    loads
        (c, 3) load cases (N).
    k_theta
        (n, n) diagonal joint stiffness (N.m/rad).
    rtol
        Relative eigenvalue tolerance of the definiteness classes.
    progress
        Called with (configurations done, total) after each chunk.
    chunk
        Configurations processed at once (bounds the memory).
    """
    coordinates = np.asarray(coordinates, dtype=float)
    loads = np.asarray(loads, dtype=float)
    m, c = coordinates.shape[0], loads.shape[0]
    spec = ScanSpec(robot={"source": robot.name}, preset="points",
                    coordinate_joints=list(robot.coordinate_joints),
                    base=[0.0] * robot.n_coordinates, axes=[], samples=None, seed=0,
                    loads=loads.tolist(), load_names=[str(j + 1) for j in range(c)],
                    k_theta=np.diag(k_theta).tolist(), rtol=rtol, chunk_size=chunk,
                    fields=[*DEFINITENESS_FIELDS, "k_c_diagonal"])
    classes = np.empty((m, c), dtype="<U3")
    tangent = np.empty((m, c), dtype="<U3")
    factor = np.empty((m, c))
    diag = np.empty((m, 3, robot.n_compliant))
    det_positive = np.zeros((m, c), dtype=bool)
    for start in range(0, m, chunk):
        end = min(m, start + chunk)
        maps = compute_maps(robot, spec, np.arange(start, end), coordinates[start:end])
        classes[start:end] = class_names(maps["k_c_class"])
        tangent[start:end] = class_names(maps["tangent_class"])
        factor[start:end] = maps["critical_factor"]
        diag[start:end] = maps["k_c_diagonal"]
        det_positive[start:end] = maps["k_c_det_positive"]
        if progress is not None:
            progress(end, m)
    return DefinitenessScan(coordinates, loads, classes, tangent, factor, diag, det_positive)
