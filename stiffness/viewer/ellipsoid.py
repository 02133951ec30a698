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


@dataclass
class RotationalBlock:
    """Rotational 3x3 block of the 6x6 Cartesian stiffness (or compliance) at the target.

    Attributes
    ----------
    formulation
        ``enhanced`` or ``conventional``.
    quantity
        ``stiffness``: the block ``K_X[3:, 3:]`` of ``K_X = C6^-1`` (N.m/rad), the rotational
        stiffness with the target free to translate; ``compliance``: ``C6[3:, 3:]``
        (rad/(N.m)).
    matrix
        (3, 3) the block, base axes.
    values
        Its eigenvalues, ascending.
    directions
        (3, 3) unit eigenvectors (columns), right-handed.
    """

    formulation: str
    quantity: str
    matrix: np.ndarray
    values: np.ndarray
    directions: np.ndarray

    @property
    def units(self) -> str:
        """Unit of ``values``."""
        return "N.m/rad" if self.quantity == "stiffness" else "rad/(N.m)"


def rotational_block(jacobian: np.ndarray, tangent_stiffness: np.ndarray, formulation: str,
                     quantity: str = "stiffness") -> RotationalBlock | None:
    """The rotational block of the 6x6 stiffness (or compliance) of a (6, n) Jacobian.

    ``C6 = J (K_theta - K_C)^-1 J^T`` (A&S eq. 10 with the full Jacobian). Returns ``None``
    when there is no 6x6 matrix to take it from: a Jacobian without rotational rows, a singular
    tangent stiffness, or (for a stiffness) a singular ``C6``, e.g. fewer than six compliant
    joints.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    if jacobian.shape[0] != 6:
        return None
    try:
        c6 = compliance(jacobian, tangent_stiffness)
    except (SingularConfigurationError, np.linalg.LinAlgError):
        return None
    c6 = 0.5 * (c6 + c6.T)
    if quantity == "stiffness":
        if np.linalg.matrix_rank(c6, tol=1e-10 * max(float(np.max(np.abs(c6))), 1e-300)) < 6:
            return None
        block = np.linalg.inv(c6)[3:, 3:]
    else:
        block = c6[3:, 3:]
    block = 0.5 * (block + block.T)
    values, vectors = np.linalg.eigh(block)
    return RotationalBlock(formulation, quantity, block, values, _right_handed(vectors))
