"""The Cartesian stiffness of an elastic model at a pose, as ``stiffness kx`` reports it.

:func:`cartesian_report` gathers what :class:`stiffness.elastic.state.ElasticState` computes
(the compliance and K_X in a formulation and a connection, K_C, the definiteness, the critical
load factor) into the JSON object of ``stiffness kx --json``: the command only resolves its
flags into a state and prints this.

Units: SI (m, N, rad, N.m/rad; N/m for prismatic joints).
"""

from __future__ import annotations

import math

import numpy as np

from stiffness.elastic.state import ElasticState
from stiffness.errors import SingularConfigurationError
from stiffness.mechanics.formulation import (
    cartesian_stiffness,
    compliance,
    definiteness,
    ellipsoid,
    subspace_stiffness,
)
from stiffness.mechanics.wrench import TWIST_ORDERS, WRENCH_ORDERS, reorder_twist

_BASIS_3 = ["vx", "vy", "vz"]


def cartesian_report(state: ElasticState, formulation: str = "enhanced",
                     connection: str | None = None, twist_order: str | None = None) -> dict:
    """K_X, the compliance, J, K_C, principal stiffnesses, definiteness and stability of
    ``state`` (JSON-ready: the numeric part of ``stiffness kx --json``).

    ``K_C``'s entries at or below :attr:`ElasticState.k_c_round_off` (``K_C_round_off``,
    the round-off of this load) are given as 0. ``K_X`` is :meth:`ElasticState.stiffness` with
    the same arguments (``None`` where it does
    not exist: ``K_X_undefined`` says why and ``K_X_subspace`` gives it on the moving
    subspace). ``J`` and ``K_C`` are those of the commanded pose; with a model file,
    ``K_theta_tangent`` and ``link_compliance`` are those of the operating pose.

    Raises
    ------
    StiffnessError
        A bad formulation, connection or twist order, a connection asked of a model with
        effects beyond joint springs, or a singular tangent stiffness.
    """
    six = state.dims(connection) == 6
    order = state.twist_order(twist_order)
    rows = slice(0, 6) if six else slice(0, 3)
    commanded = state.commanded
    undefined = None  # why K_X does not exist here (the compliance does)
    if connection is not None:
        jac = commanded.body_jacobian()
        axes = "target frame body axes (left-invariant twist basis)"
        k_c = commanded.k_c_twist if connection == "twist" else np.zeros_like(commanded.k_c)
        try:
            k_x = state.connection_stiffness(connection)
            c_x = np.linalg.inv(k_x)
        except SingularConfigurationError as exc:  # J_b singular: C = J_b T^-1 J_b^T exists
            k_x, undefined = None, str(exc)
            c_x = compliance(jac, np.diag(state.k_theta) - k_c)
    else:  # base axes: the model's compliance, its effects included
        jac = commanded.jacobian[rows]
        c_x = state.compliance(rows, formulation)
        axes = "base frame axes at the target"
        k_c = commanded.k_c
        try:
            k_x = cartesian_stiffness(c_x)
        except SingularConfigurationError as exc:
            k_x, undefined = None, str(exc)
    round_off = state.k_c_round_off
    k_c = np.where(np.abs(k_c) <= round_off, 0.0, k_c)  # round-off of this load: 0
    wrench = commanded.wrench[: 6 if six else 3]
    blocks = _principal_by_block(c_x) if six and k_x is not None else None
    if six:
        c_x, wrench = reorder_twist(c_x, order), reorder_twist(wrench, order)
        k_x = None if k_x is None else reorder_twist(k_x, order)
        if order == "w-v":
            jac = jac[[3, 4, 5, 0, 1, 2]]
    ell = None if k_x is None else ellipsoid(k_x)
    critical = state.critical_load_factor
    if undefined is not None and critical is not None and critical < 1.0:
        undefined = (f"the arm is unstable under this load (K_theta - K_C turns singular at "
                     f"{critical:.4g} times the wrench), and {undefined}")
    out = {
        "formulation": formulation,
        "connection": connection,
        "wrench": wrench.tolist(),
        "wrench_basis": WRENCH_ORDERS[order] if six else ["fx", "fy", "fz"],
        "basis": TWIST_ORDERS[order] if six else _BASIS_3,
        "axes": axes,
        "position": commanded.position.tolist(),
        "J": jac.tolist(),
        "K_theta": state.k_theta.tolist(),
        "K_C": k_c.tolist(),
        "K_C_round_off": round_off,
        "K_X": None if k_x is None else k_x.tolist(),
        "K_X_undefined": undefined,
        "K_X_subspace": None if k_x is not None else _subspace_json(c_x),
        "compliance": c_x.tolist(),
        "K_X_symmetric": None if ell is None else bool(ell.symmetric),
        "eigenvalues": None if ell is None else ell.values.tolist(),
        "eigenvectors": None if ell is None else ell.directions.tolist(),
        "principal_by_block": blocks,
        "definiteness": {**state.definiteness,
                         "K_X": None if k_x is None else definiteness(k_x)},
        "stable": bool(state.stable),
        "critical_load_factor": critical if math.isfinite(critical) else None,
    }
    if state.model.fitted is not None and connection is None:  # a model file's
        lin = state.linearisation(formulation)
        out["K_theta_tangent"] = np.diag(lin.k_tangent).tolist()
        out["link_compliance"] = lin.link_compliance[rows, rows].tolist()
    return out


def _principal_by_block(c_x: np.ndarray) -> dict:
    """Principal stiffnesses of a 6-D compliance (translation rows first) block by block, each
    in its own unit: translational (N/m) with the rotation free, the eigenvalues of the inverse
    of the compliance's translational block, and rotational (N.m/rad) with the translation
    free, those of the inverse of its rotational block."""
    def values(block: np.ndarray) -> list[float]:
        return sorted(1.0 / np.linalg.eigvalsh(0.5 * (block + block.T)).astype(float))

    return {"translational": {"values": values(c_x[:3, :3]), "unit": "N/m",
                              "note": "rotations free"},
            "rotational": {"values": values(c_x[3:, 3:]), "unit": "N.m/rad",
                           "note": "translations free"}}


def _subspace_json(c_x: np.ndarray) -> dict:
    """Where K_X is undefined (singular compliance): the stiffness on the moving subspace.

    ``K_X`` is the pseudo-inverse of the compliance, ``eigenvalues`` its principal values on the
    ``moving_directions`` (rows: unit displacement directions); along ``rigid_directions``
    (rows: unit wrench directions) the target does not move, the stiffness is unbounded.
    """
    sub = subspace_stiffness(c_x)
    return {"rank": sub.rank, "K_X": sub.stiffness.tolist(), "eigenvalues": sub.values.tolist(),
            "moving_directions": sub.moving.T.tolist(), "rigid_directions": sub.rigid.T.tolist()}
