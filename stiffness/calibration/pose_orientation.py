"""What a pose fit compares: marker positions and, where measured, marker orientations.

Orientations (``<marker>_rx, _ry, _rz`` of a pose campaign: the rotation vector of the marker's
frame in the measuring frame) are predicted from the pose model's own points, so every
parameter family acts on them without a rotation hook of its own: each marker is evaluated as
four points of an auxiliary :class:`~stiffness.calibration.pose_model.PoseModel`, its position
``p`` and the points ``a_i`` at its offset plus :data:`AXIS_LENGTH_M` along each axis ``e_i``
of its own frame (the robot frame's axes turned by its declared ``rotation``, a 6-D probe's
mounting), all four sharing the marker's offset correction. With ``v_i = a_i - p`` (measuring
axes) the predicted orientation is the rotation nearest ``[v_x v_y v_z] / L`` (its polar
factor; exactly the frame's rotation where the link is rigid at the marker), and its derivative,
as a rotation vector in measuring axes, is ``d theta = sum_i v_i x d v_i / (2 L^2)``: exact for
a rigid frame, since every family's point columns are. An oriented marker's fitted mounting
turn ``delta`` (the ``markers`` family, rad, its own axes) turns that rotation on the right,
``R exp(delta)``, adding ``R exp(delta) Jr(delta) d delta`` to ``d theta``
(:meth:`~stiffness.elastic.effects.kinematic_errors.MarkerOffsets.turned`); it moves no point.
The residual of an orientation is ``e = log(R_pred R_meas^T)`` (rad, measuring axes), with
derivative ``Jl(e)^-1 d theta``.

The fit stacks positions (m) and orientations weighted by ``w = sigma_t / sigma_r`` (m/rad),
the declared position and rotation noise stds, as deflection campaigns do
(:mod:`stiffness.calibration.fitting`, "Rotations"): one scale whitens both kinds, and every
sum of squares is in position-noise units.

Units: SI (m, rad).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pinocchio as pin

from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_model import ROW_BLOCK, Marker, PoseModel
from stiffness.elastic.effects.kinematic_errors import MarkerOffsets
from stiffness.elastic.effects.pose_face import RowTerms
from stiffness.errors import StiffnessError

#: Distance (m) of the auxiliary points from a marker along its frame's axes.
AXIS_LENGTH_M = 0.1


def rotation_weight(campaign: PoseCampaign) -> float | None:
    """``sigma_t / sigma_r`` (m/rad) of a campaign with measured orientations, ``None``
    without them.

    Raises
    ------
    StiffnessError
        Orientations measured without both noise stds declared.
    """
    if campaign.rotations is None:
        return None
    if campaign.noise_std is None or campaign.noise_std_rotation is None:
        raise StiffnessError("a pose campaign with orientation columns needs both "
                             "[measurement] noise_std and noise_std_rotation (they weigh "
                             "rotations against positions); declare them")
    return campaign.noise_std / campaign.noise_std_rotation


class PoseObservations:
    """The measured components of ``campaign`` and their prediction under ``model``.

    Parameters
    ----------
    model
        The pose model.
    campaign
        The campaign (its markers in the model's order).
    rows
        The rows' terms (:func:`stiffness.calibration.pose_fit.rows_of`).
    """

    def __init__(self, model: PoseModel, campaign: PoseCampaign, rows: list[RowTerms]) -> None:
        self.model, self.rows = model, rows
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None
        self._handed = False  # whether a Jacobian was computed (only the first is kept)
        self.observed = np.isfinite(campaign.positions)
        self.positions = campaign.positions
        self.weight = rotation_weight(campaign)
        self.shape = campaign.positions.shape
        if self.weight is None or campaign.rotations is None:
            self.seen_rotation = np.zeros(self.shape, dtype=bool)
            self.aux: PoseModel | None = None
            return
        self.seen_rotation = np.isfinite(campaign.rotations)
        self.inverse_measured = np.array([[pin.exp3(r).T if np.all(np.isfinite(r)) else
                                           np.eye(3) for r in row] for row in campaign.rotations])
        self.aux, self.expand = _auxiliary(model)

    @property
    def size(self) -> int:
        """Number of measured components (positions and rotations)."""
        return int(self.observed.sum() + self.seen_rotation.sum())

    def component_rows(self) -> np.ndarray:
        """(N,) the campaign row of each measured component, in :meth:`evaluate`'s order."""
        return np.concatenate([np.nonzero(self.observed)[0],
                               np.nonzero(self.seen_rotation)[0]])

    def evaluate(self, x: np.ndarray, jacobian: bool = True, keep: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """Predicted minus measured (N,): positions (m), then ``w`` times the orientation
        errors (rad), and its Jacobian (N, p) when asked for.

        The last result is kept: asked again at the same ``x`` (a fit's first residual and
        Jacobian, at the start its identifiability check evaluated), it is not recomputed.
        Only the first Jacobian is kept (none when ``keep`` is false: the caller may then
        change it in place), and handed out once: the later ones (a fit's steps) are never
        asked for again, and a large campaign's solver then holds no extra copy.
        """
        last = self._last
        if last is not None and np.array_equal(last[0], x) and (last[2] is not None
                                                                or not jacobian):
            if jacobian:
                self._last = (last[0], last[1], None)
            return last[1].copy(), last[2] if jacobian else None
        residual = np.empty(self.size)
        jac = np.empty((self.size, self.model.size)) if jacobian else None
        for rows in self._row_blocks():
            index = self.components_of(rows)
            residual[index], part = self._evaluate(x, jacobian, rows)
            if jac is not None and part is not None:
                jac[index] = part
        self._last = (np.array(x, dtype=float), residual,
                      None if self._handed or not keep else jac)
        self._handed = self._handed or jac is not None
        return residual.copy(), jac

    def blocks(self, x: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """:meth:`evaluate` in blocks of :data:`~stiffness.calibration.pose_model.ROW_BLOCK`
        rows, what a large campaign's fit holds at once: per block, its components' indices
        in :meth:`evaluate`'s vector, their residuals and Jacobian (components, p)."""
        for rows in self._row_blocks():
            residual, jac = self._evaluate(x, True, rows)
            assert jac is not None
            yield self.components_of(rows), residual, jac

    def _row_blocks(self) -> Iterator[np.ndarray]:
        """The campaign rows in blocks of :data:`~stiffness.calibration.pose_model.
        ROW_BLOCK` (a model of row-at-once families evaluates that many together)."""
        n = self.shape[0]
        for start in range(0, n, ROW_BLOCK):
            yield np.arange(start, min(n, start + ROW_BLOCK))

    def jacobian_rows(self, x: np.ndarray, components: np.ndarray) -> np.ndarray:
        """The rows ``components`` (indices into :meth:`evaluate`'s vector) of the Jacobian
        (len(components), p) at ``x``: only their campaign rows evaluated."""
        rows = np.unique(self.component_rows()[components])
        _, jac = self._evaluate(x, True, rows)
        assert jac is not None
        return jac[np.searchsorted(self.components_of(rows), components)]

    def components_of(self, rows: np.ndarray) -> np.ndarray:
        """The indices into :meth:`evaluate`'s vector of the components of ``rows``
        (ascending campaign rows), ascending: what :meth:`_evaluate` of them returns."""
        counts = [self.observed.reshape(self.shape[0], -1).sum(axis=1),
                  self.seen_rotation.reshape(self.shape[0], -1).sum(axis=1)]
        out, before = [], 0
        for count in counts:
            starts = np.concatenate([[0], np.cumsum(count)[:-1]]) + before
            sizes = count[rows]
            out.append(np.repeat(starts[rows] - np.cumsum(sizes) + sizes, sizes)
                       + np.arange(sizes.sum()))
            before += int(count.sum())
        return np.concatenate(out).astype(int)

    def _evaluate(self, x: np.ndarray, jacobian: bool, rows: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`evaluate`'s components of ``rows`` (ascending campaign rows) alone."""
        terms = [self.rows[i] for i in rows]
        observed = self.observed[rows]
        measured = self.positions[rows][observed]
        if self.aux is None:
            y, jac = self.model.evaluate(x, terms, jacobian)
            return (y[observed] - measured,
                    None if jac is None else self._observed_rows(jac, observed))
        y, rot, jac_p, jac_r = self.oriented(x, jacobian, terms)
        w = self.weight
        assert w is not None  # orientations are fitted only with their weight
        seen = self.seen_rotation[rows]
        error = np.array([[pin.log3(r @ inv) for r, inv in zip(rr, ii, strict=True)]
                          for rr, ii in zip(rot, self.inverse_measured[rows], strict=True)])
        error = error.reshape(rot.shape[:3])
        residual = np.concatenate([y[observed] - measured, w * error[seen]])
        if not jacobian:
            return residual, None
        assert jac_p is not None and jac_r is not None
        left = np.array([[_inverse_left_jacobian(e) for e in row] for row in error])
        jac_e = np.einsum("nmab,nmbp->nmap", left.reshape(rot.shape[:2] + (3, 3)), jac_r)
        return residual, np.vstack([jac_p[observed], w * jac_e[seen]])

    @staticmethod
    def _observed_rows(jac: np.ndarray, observed: np.ndarray) -> np.ndarray:
        """The measured components' rows of a (n, M, 3, p) Jacobian: a view when every
        component is measured (a large campaign's Jacobian is not copied)."""
        if observed.all():
            return jac.reshape(-1, jac.shape[-1])
        return jac[observed]

    def split(self, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Measured minus predicted positions (n, M, 3) in m and orientations (n, M, 3) in
        rad (or ``None`` without them), NaN where not measured, from :meth:`evaluate`'s
        predicted-minus-measured vector."""
        n_pos = int(self.observed.sum())
        pos = np.full(self.shape, np.nan)
        pos[self.observed] = -residual[:n_pos]
        if self.aux is None:
            return pos, None
        assert self.weight is not None
        rot = np.full(self.shape, np.nan)
        rot[self.seen_rotation] = -residual[n_pos:] / self.weight
        return pos, rot

    def oriented(self, x: np.ndarray, jacobian: bool = True,
                 rows: list[RowTerms] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Positions (n, M, 3), orientations (n, M, 3, 3), both in measuring axes, and their
        Jacobians: d y / d x (n, M, 3, p) and the rotation vector's d theta / d x
        (n, M, 3, p) (module docstring), of ``rows`` (default every row)."""
        assert self.aux is not None
        rows = self.rows if rows is None else rows
        y4, j4 = self.aux.evaluate(self.expand @ x, rows, jacobian)
        n, m = y4.shape[0], y4.shape[1] // 4
        y4 = y4.reshape(n, m, 4, 3)
        axes, rot = _frames(y4)
        rot, turn = _turned(self.model, x, rot)
        if j4 is None:
            return y4[:, :, 0], rot, None, None
        j4 = (j4 @ self.expand).reshape(n, m, 4, 3, -1)
        dv = j4[:, :, 1:] - j4[:, :, :1]                    # (n, M, 3, 3, p)
        dtheta = np.cross(axes[..., None], dv, axisa=-2, axisb=-2, axisc=-2).sum(axis=2)
        return y4[:, :, 0], rot, j4[:, :, 0], dtheta / (2.0 * AXIS_LENGTH_M ** 2) + turn


def orientation_errors(model: PoseModel, x: np.ndarray, campaign: PoseCampaign,
                       rows: list[RowTerms]) -> np.ndarray:
    """(n, M) angle (rad) of each measured orientation's error ``|log(R_pred R_meas^T)|``
    under ``model`` at ``x`` (NaN where not measured, all NaN without orientation columns)."""
    shape = campaign.positions.shape[:2]
    if campaign.rotations is None:
        return np.full(shape, np.nan)
    aux, expand = _auxiliary(model)
    y4, _ = aux.evaluate(expand @ x, rows, jacobian=False)
    _, rot = _frames(y4.reshape(shape[0], shape[1], 4, 3))
    rot, _ = _turned(model, x, rot)
    out = np.full(shape, np.nan)
    for i, k in np.ndindex(shape):
        measured = campaign.rotations[i, k]
        if np.all(np.isfinite(measured)):
            out[i, k] = np.linalg.norm(pin.log3(rot[i, k] @ pin.exp3(measured).T))
    return out


def _frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From (n, M, 4, 3) points (each marker and its three axis points, measuring axes): the
    axis vectors ``v_i`` as rows (n, M, 3, 3) and the rotations (n, M, 3, 3) nearest
    ``[v_x v_y v_z] / L`` (polar factors)."""
    axes = points[:, :, 1:] - points[:, :, :1]
    u, _, vt = np.linalg.svd(np.swapaxes(axes, -1, -2) / AXIS_LENGTH_M)
    return axes, u @ vt


def _turned(model: PoseModel, x: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The orientations ``rot`` (n, M, 3, 3) turned by the oriented markers' mounting turns in
    ``x`` and the turns' columns of ``d theta`` (n, M, 3, p)
    (:meth:`~stiffness.elastic.effects.kinematic_errors.MarkerOffsets.turned`)."""
    cols = np.zeros(rot.shape[:-1] + (model.size,))
    sl = model.slices().get("markers")
    if sl is None:
        return rot, cols
    rot, cols[..., sl] = MarkerOffsets.turned(model, x[sl], rot)
    return rot, cols


def _auxiliary(model: PoseModel) -> tuple[PoseModel, np.ndarray]:
    """The four-point model of ``model``'s markers and the (p_aux, p) map of the parameters
    (each marker's offset correction shared by its four points)."""
    points = [Marker(f"{m.name}#{i}", m.frame, np.asarray(m.offset, float)
                     + AXIS_LENGTH_M * (np.eye(4, 3, -1) @ np.asarray(m.rotation, float).T)[i])
              for m in model.markers for i in range(4)]
    aux = PoseModel(model.robot, points, model.families, (model.rotation0, model.translation0),
                    model.loads, model.settings)
    index = {p.label: i for i, p in enumerate(model.parameters)}
    own = model.slices().get("markers")
    theirs = aux.slices().get("markers")
    expand = np.zeros((aux.size, model.size))
    for j, p in enumerate(aux.parameters):
        if own is not None and theirs is not None and theirs.start <= j < theirs.stop:
            point, axis = divmod(j - theirs.start, 3)
            expand[j, own.start + 3 * (point // 4) + axis] = 1.0
        else:
            expand[j, index[p.label]] = 1.0
    return aux, expand


def _inverse_left_jacobian(e: np.ndarray) -> np.ndarray:
    """``Jl(e)^-1`` of SO(3): ``d log(exp(d) R) = Jl(log R)^-1 d`` (``Jl(e) = Jr(e)^T``)."""
    return pin.Jlog3(pin.exp3(e)).T
