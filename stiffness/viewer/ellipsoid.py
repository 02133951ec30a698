"""Ellipsoid algebra: principal values and axes of a translational stiffness or compliance.

With ``M`` the drawn matrix (the stiffness ``K_X = C^-1`` in N/m, or the compliance
``C = J (K_theta - K_C)^-1 J^T`` in m/N) and ``M = V diag(lambda) V^T`` its eigen-decomposition
(symmetric part, eigenvalues ascending, ``det V = +1``), an ellipsoid is the unit sphere under
the transform ``[V diag(radii), c]`` (:func:`ellipsoid_transform`).

Units: SI (m, N, rad; N/m, m/N; N.m/rad for joints).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stiffness.errors import SingularConfigurationError, UnknownNameError
from stiffness.mechanics.formulation import cartesian_stiffness, compliance

#: What the ellipsoids can show.
QUANTITIES = ("stiffness", "compliance")


@dataclass
class PrincipalEllipsoid:
    """Eigen-decomposition of one formulation's translational stiffness or compliance.

    Attributes
    ----------
    formulation
        ``enhanced`` or ``conventional``.
    quantity
        ``stiffness`` (``matrix`` is K_X, N/m) or ``compliance`` (``matrix`` is C, m/N).
    matrix
        (3, 3) drawn matrix, base axes at the target.
    values
        Eigenvalues of the symmetric part of ``matrix``, ascending (N/m or m/N); ``inf`` for an
        unbounded stiffness.
    directions
        (3, 3) unit eigenvectors (columns), right-handed (``det = +1``).
    compliance
        (3, 3) translational compliance C (m/N).
    stiffness
        (3, 3) K_X = C^-1 (N/m), or ``None`` where C is singular.
    principal_stiffness
        Principal stiffnesses (N/m) along ``directions``: ``values`` for a stiffness, their
        inverses for a compliance (``inf`` where a compliance vanishes).
    """

    formulation: str
    quantity: str
    matrix: np.ndarray
    values: np.ndarray
    directions: np.ndarray
    compliance: np.ndarray
    stiffness: np.ndarray | None
    principal_stiffness: np.ndarray

    @property
    def units(self) -> str:
        """Unit of ``values``."""
        return "N/m" if self.quantity == "stiffness" else "m/N"

    @property
    def min_stiffness(self) -> float:
        """Smallest principal stiffness (N/m); negative when K_X is indefinite."""
        return float(np.min(self.principal_stiffness))


def _right_handed(vectors: np.ndarray) -> np.ndarray:
    vectors = np.array(vectors, dtype=float)
    if np.linalg.det(vectors) < 0.0:
        vectors[:, -1] *= -1.0
    return vectors


def principal_ellipsoid(jacobian: np.ndarray, tangent_stiffness: np.ndarray, formulation: str,
                        quantity: str = "stiffness") -> PrincipalEllipsoid:
    """Principal values and axes of the translational stiffness (or compliance) at the target.

    Parameters
    ----------
    jacobian
        (3, n) translational target Jacobian (m/rad), base axes.
    tangent_stiffness
        (n, n) ``K_theta - K_C`` (enhanced) or ``K_theta`` (conventional), N.m/rad.
    formulation
        Name stored with the result.
    quantity
        ``stiffness`` (draw K_X, N/m) or ``compliance`` (draw C, m/N).

    Raises
    ------
    SingularConfigurationError
        If the tangent joint stiffness is singular (the buckling limit).
    """
    if quantity not in QUANTITIES:
        raise UnknownNameError(f"quantity must be one of {', '.join(QUANTITIES)}, got "
                               f"{quantity!r}", name=quantity, choices=QUANTITIES)
    c = compliance(jacobian, tangent_stiffness)
    c = 0.5 * (c + c.T)
    try:
        k = cartesian_stiffness(c)
        k = 0.5 * (k + k.T)
    except SingularConfigurationError:
        k = None
    if quantity == "stiffness" and k is not None:
        values, vectors = np.linalg.eigh(k)
        principal_k = values.copy()
        matrix = k
    else:
        c_values, vectors = np.linalg.eigh(c)
        tol = 1e-12 * max(float(np.max(np.abs(c_values))), 1e-300)
        with np.errstate(divide="ignore"):
            principal_k = np.where(np.abs(c_values) > tol, 1.0 / c_values, np.inf)
        if quantity == "compliance":
            values, matrix = c_values, c
        else:  # singular compliance: stiffness unbounded along its null directions
            order = np.argsort(principal_k)
            values, vectors, principal_k = principal_k[order], vectors[:, order], principal_k[order]
            matrix = c
    vectors = _right_handed(vectors)
    return PrincipalEllipsoid(formulation, quantity, matrix, values, vectors, c, k, principal_k)


def ellipsoid_transform(center: np.ndarray, directions: np.ndarray, radii: np.ndarray
                        ) -> np.ndarray:
    """4x4 transform of the unit sphere onto an ellipsoid: ``[directions diag(radii), center]``.

    ``directions`` must be a rotation (unit columns, ``det = +1``); ``radii`` in m.
    """
    t = np.eye(4)
    t[:3, :3] = np.asarray(directions, dtype=float) * np.asarray(radii, dtype=float)[None, :]
    t[:3, 3] = center
    return t
