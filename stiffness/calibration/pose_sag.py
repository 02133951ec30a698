"""The pose model's sag between its plain passes (:meth:`stiffness.calibration.pose_model.
PoseModel._loaded_rows`): where the passes contract at a steady ratio, the jump to their limit.

Units: the sag's own (rad, or m for a prismatic coordinate).
"""

from __future__ import annotations

import numpy as np

#: Relative spread of the ratio of successive sag steps under which a row's passes follow one
#: slow mode (:func:`sag_jump`).
SAG_STEADY_RATIO = 1e-3


def sag_jump(steps: np.ndarray, size: np.ndarray, left: int, tolerance: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """Where the sag's plain passes contract at a steady ratio, the jump to their limit.

    Parameters
    ----------
    steps
        (3, p, nv) each pending row's last three plain steps ``s_0, s_1, s_2`` (rad, m; a
        pass's new sag minus its start), newest first.
    size
        (p,) the largest component of the newest step.
    left
        Passes left in the attempt.
    tolerance
        The sag's tolerance (rad or m; the pose model's ``SAG_TOLERANCE``).

    Returns
    -------
    jump : (p, nv)
        Aitken's extrapolation ``s_0 r / (1 - r)`` to the limit of passes whose steps
        ``s_2, s_1, s_0`` (newest last) shrink by the ratio ``r = s_0 . s_1 / |s_1|^2`` (a
        dominant mode: ``s_1 . s_2 / |s_2|^2`` the same to :data:`SAG_STEADY_RATIO`), zero
        elsewhere.
    hopeless : (p,)
        Rows whose plain passes, at that ratio, would not reach ``tolerance`` within
        ``left`` more passes (or never: ``|r| >= 1``): the attempt fails there, as it did
        before the jumps.
    """
    ratio, before = np.sum(steps[:2] * steps[1:], axis=2) / np.sum(steps[1:] ** 2, axis=2)
    steady = np.abs(ratio - before) <= SAG_STEADY_RATIO * np.abs(ratio)  # no step is nil
    jump, hopeless = np.zeros(steps.shape[1:]), np.zeros(len(size), dtype=bool)
    if steady.any():
        r = ratio[steady]
        with np.errstate(divide="ignore"):  # a ratio of exactly zero: no pass needed
            needed = np.log(tolerance / size[steady]) / np.log(np.abs(r))
        hopeless[steady] = (np.abs(r) >= 1.0) | (needed > left)
        going = ~hopeless[steady]
        jump[np.flatnonzero(steady)[going]] = (steps[0][steady][going]
                                               * (r[going] / (1.0 - r[going]))[:, None])
    return jump, hopeless
