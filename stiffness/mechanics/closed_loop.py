"""Closed-loop reduction of the elastostatics: velocity map, closure curvature, reduced K_C.

The one place where a loop closure enters the stiffness, for a stack of configurations (the
single-pose API of :mod:`stiffness.mechanics.formulation` is the stack of one; the batched API
of :mod:`stiffness.batch.kernels` calls the same functions on many).

With ``c(q) = 0`` the loop residual in world axes (rows ``p_b - p_a`` of point pairs), ``C`` its
Jacobian (R, nv), ``Hc`` its Hessian (R, nv, nv), ``theta`` the compliant joints and ``p`` the
passive ones:

* velocity map ``S`` (nv, n): identity on the compliant joints, ``S_p = -pinv(C_p) C_theta`` on
  the passive ones, zero on the other coordinate joints (rigid);
* closure curvature ``dS_p[:, a, b] = d2 q_p / d theta_a d theta_b``: differentiating
  ``C S = 0`` along the closed loop, ``C_p dS_p[:, a, b] = -Hc[S_a, S_b]``;
* reduced complementary stiffness of a generalized force ``tau = J^T W`` of the tree,
  ``K_C = S^T (sum_k W_k H_k) S + sum_p tau_p dS_p`` (the derivative of ``S^T tau``), equal to the
  Lagrange-multiplier form ``S^T (sum_k W_k H_k - sum_j lambda_j Hc_j) S`` with
  ``C_p^T lambda = tau_p`` (design notes, closed-loop K_C).

``S`` and ``dS_p`` depend only on the loop's own geometry (not on the load, and not on joints
that move the loop rigidly), so a batch computes them once per distinct closure and any number
of load cases reuse them as products.

Rank test (one for the whole toolkit): the passive joints are determined where every singular
value of ``C_p`` exceeds ``LOOP_RANK_RTOL * max(1, max |C_p|)``; the pseudo-inverse cuts
singular values below ``LOOP_RANK_RTOL`` times the largest. Where the rank falls short, the
passive motions the constraints leave free (the null space of ``C_p``, e.g. a rod spinning about
its own axis) are *idle* when they do not move the target (less than :data:`IDLE_MOTION_TOL`
m per unit rate, relative to the target's passive Jacobian): the configuration stays valid and
the minimum-norm pseudo-inverse keeps those motions still. Only a free motion that moves the
target makes the configuration invalid (the target's position depends on it).

Mimic followers move with their leaders: the velocity map starts from the compliant joints'
*base projection* (identity on the compliant joints, the multiplier on each follower).

Units: C in m/rad (m/m for prismatic joints), Hc in m/rad^2, K_C in N.m/rad.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Relative rank tolerance of the passive block of the loop Jacobian (see module docstring).
LOOP_RANK_RTOL = 1e-9
#: A free passive motion moving the target by less than this (m per unit rate, times
#: ``max(1, max |J_target,p|)``) is idle.
IDLE_MOTION_TOL = 1e-8


@dataclass
class ClosureDerivatives:
    """First and second derivatives of the passive joints along the closed loop, stacked.

    Attributes
    ----------
    projection
        (m, nv, n) velocity map ``S`` (q_dot = S theta_dot).
    curvature
        (m, n_p, n, n) ``dS_p`` (rad/rad^2), symmetric in the last two axes.
    valid
        (m,) False where the target's position depends on a passive motion the loop leaves
        free (a loop singularity); the other arrays hold NaN there.
    rank
        (m,) numerical rank of ``C_p``.
    """

    projection: np.ndarray
    curvature: np.ndarray
    valid: np.ndarray
    rank: np.ndarray


def passive_pseudo_inverse(c_p: np.ndarray, target_passive: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pseudo-inverses (m, n_p, R), validity and rank of the passive loop Jacobians (m, R, n_p).

    Without ``target_passive`` an entry is valid where ``C_p`` has full column rank; with it
    ((m, 3, n_p): the target position's Jacobian on the passive joints), also where every
    motion the constraints leave free is idle (:func:`idle_motions_leave_target`).

    The toolkit's one rank test (:data:`LOOP_RANK_RTOL`). Decided by a stacked SVD, except
    for one or two passive coordinates with a well-conditioned block
    (``s_min >= 1e-2 s_max``, and ``s_min`` far above the tolerance), where the closed-form
    normal equations give the same decision and the same pseudo-inverse to ~1e-12 relative.
    """
    m, rows, n_p = c_p.shape
    scale = np.maximum(1.0, np.abs(c_p).max(axis=(1, 2))) if m else np.ones(0)
    pinv = np.empty((m, n_p, rows))
    valid = np.zeros(m, dtype=bool)
    rank = np.zeros(m, dtype=int)
    fast = np.zeros(m, dtype=bool)
    if n_p in (1, 2) and m:
        gram = np.swapaxes(c_p, 1, 2) @ c_p
        if n_p == 1:
            low, high = gram[:, 0, 0], gram[:, 0, 0]
            inverse = 1.0 / np.where(low > 0, low, 1.0)[:, None, None]
        else:
            a, b, c = gram[:, 0, 0], gram[:, 0, 1], gram[:, 1, 1]
            high = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
            det = a * c - b * b
            low = det / np.where(high > 0, high, 1.0)
            inverse = np.stack([np.stack([c, -b], -1), np.stack([-b, a], -1)], 1)
            inverse /= np.where(det > 0, det, 1.0)[:, None, None]
        fast = (low >= 1e-4 * high) & (low > 1e4 * (LOOP_RANK_RTOL * scale) ** 2)
        pinv[fast] = (inverse @ np.swapaxes(c_p, 1, 2))[fast]
        valid[fast], rank[fast] = True, n_p
    slow = ~fast
    if slow.any():
        u, s, vt = np.linalg.svd(c_p[slow], full_matrices=False)
        rank[slow] = np.sum(s > LOOP_RANK_RTOL * scale[slow, None], axis=1)
        valid[slow] = rank[slow] == n_p
        cutoff = LOOP_RANK_RTOL * s[:, :1]
        s_inv = np.where(s > cutoff, 1.0 / np.where(s > cutoff, s, 1.0), 0.0)
        pinv[slow] = (np.swapaxes(vt, 1, 2) * s_inv[:, None, :]) @ np.swapaxes(u, 1, 2)
    if target_passive is not None and not valid.all():
        valid |= idle_motions_leave_target(c_p, rank, target_passive, ~valid)
    return pinv, valid, rank


def idle_motions_leave_target(c_p: np.ndarray, rank: np.ndarray, target_passive: np.ndarray,
                              which: np.ndarray) -> np.ndarray:
    """Whether the passive motions that ``C_p`` (m, R, n_p) leaves free move the target.

    For the entries ``which`` (m,) bool: True where no vector of the null space of ``C_p``
    (beyond its ``rank``) moves the target by more than :data:`IDLE_MOTION_TOL` (m per unit
    rate, relative to ``max(1, max |J|)``), with ``J = target_passive`` (m, 3, n_p).
    """
    out = np.zeros(c_p.shape[0], dtype=bool)
    for i in np.flatnonzero(which):
        null = np.linalg.svd(c_p[i])[2][rank[i]:].T
        j = target_passive[i]
        moved = np.linalg.norm(j @ null, axis=0)
        out[i] = not np.any(moved > IDLE_MOTION_TOL * max(1.0, float(np.abs(j).max(initial=0.0))))
    return out


def base_projection(compliant_v: np.ndarray, nv: int,
                    followers: Sequence[tuple[int, int, float]] = ()) -> np.ndarray:
    """(nv, n) rates of the tree joints per compliant rate, loops aside: identity on the
    compliant joints, ``multiplier`` times the leader's on each mimic follower
    (``followers``: (follower v index, leader v index, multiplier))."""
    n = compliant_v.shape[0]
    base = np.zeros((nv, n))
    base[compliant_v, np.arange(n)] = 1.0
    for follower, leader, multiplier in followers:
        base[follower] = multiplier * base[leader]
    return base


def velocity_map(c: np.ndarray, compliant_v: np.ndarray, passive_v: np.ndarray,
                 base: np.ndarray | None = None, target_passive: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Velocity maps S (m, nv, n) of a stack of loop Jacobians ``c`` (m, R, nv).

    ``base`` (nv, n): the :func:`base_projection` (default: identity on the compliant joints);
    ``target_passive``: see :func:`passive_pseudo_inverse`. Returns S (NaN rows where invalid),
    the passive pseudo-inverses (m, n_p, R), the validity and the rank of
    :func:`passive_pseudo_inverse`.
    """
    m, _, nv = c.shape
    if base is None:
        base = base_projection(compliant_v, nv)
    pinv, valid, rank = passive_pseudo_inverse(c[:, :, passive_v], target_passive)
    proj = np.repeat(base[None], m, axis=0)
    proj[:, passive_v, :] = -(pinv @ (c @ base))
    if not valid.all():
        proj[~valid] = np.nan
    return proj, pinv, valid, rank


def closure_curvature(pinv: np.ndarray, hss: np.ndarray) -> np.ndarray:
    """``dS_p = -pinv(C_p) Hc[S, S]`` (m, n_p, n, n) from ``hss[:, r, a, b] = Hc_r[S_a, S_b]``
    (m, R, n, n) and the passive pseudo-inverses of :func:`velocity_map`."""
    m, rows, n, _ = hss.shape
    return -(pinv @ hss.reshape(m, rows, n * n)).reshape(m, pinv.shape[1], n, n)


def closure_derivatives(c: np.ndarray, hc: np.ndarray, compliant_v: np.ndarray,
                        passive_v: np.ndarray, base: np.ndarray | None = None,
                        target_passive: np.ndarray | None = None) -> ClosureDerivatives:
    """Velocity map and closure curvature of a stack of closed configurations.

    Parameters
    ----------
    c
        (m, R, nv) Jacobian of the world-axes loop residual.
    hc
        (m, R, nv, nv) its Hessian, ``hc[:, r, i, j] = d C[r, i] / d q_j``.
    compliant_v, passive_v
        Velocity indices of the compliant and of the passive joints.
    base, target_passive
        See :func:`velocity_map`.
    """
    proj, pinv, valid, rank = velocity_map(c, compliant_v, passive_v, base, target_passive)
    hss = np.swapaxes(proj, 1, 2)[:, None] @ hc @ proj[:, None]  # (m, R, n, n)
    return ClosureDerivatives(proj, closure_curvature(pinv, hss), valid, rank)


def reduced_hessian(hessian: np.ndarray, force_passive: np.ndarray, projection: np.ndarray,
                    curvature: np.ndarray) -> np.ndarray:
    """``S^T H S + sum_p tau_p dS_p``: the closed-loop K_C of a tree term, broadcast.

    Parameters
    ----------
    hessian
        (..., nv, nv) tree term ``sum_k W_k H_k`` (N.m/rad), or the unit-wrench Hessians.
    force_passive
        (..., n_p) passive components of the tree's generalized force ``J^T W`` (N.m), or
        the passive columns of the Jacobian rows for unit wrenches.
    projection
        (..., nv, n) velocity map S.
    curvature
        (..., n_p, n, n) closure curvature dS_p.
    """
    tree = np.swapaxes(projection, -1, -2) @ hessian @ projection
    return tree + closure_term(force_passive, curvature)


def closure_term(force_passive: np.ndarray, curvature: np.ndarray) -> np.ndarray:
    """``sum_p tau_p dS_p`` (..., n, n): the closure part of :func:`reduced_hessian`."""
    n_p, n = curvature.shape[-3], curvature.shape[-1]
    lead = np.broadcast_shapes(force_passive.shape[:-1], curvature.shape[:-3])
    flat = curvature.reshape(*curvature.shape[:-3], n_p, n * n)
    return (force_passive[..., None, :] @ flat)[..., 0, :].reshape(*lead, n, n)
