"""Fitting a :class:`~stiffness.calibration.pose_model.PoseModel` to a pose campaign.

A pose campaign's observation is :class:`PoseProblem` (predicted minus measured marker
positions and orientations, their analytic Jacobian, the parameters' bounds and layout); the
fit is the one engine of both campaign kinds (:mod:`stiffness.calibration.solver`).

Identifiability. Only an identifiable set of parameters is fitted, judged as deflection fits
judge theirs (:func:`stiffness.calibration.identifiability.identifiable`): the regressor (d y
/ d x over every measured component, each column scaled by its parameter's typical size) is
reduced family by family, in the order the families were chosen ("no effect" and "merged"
parameters, the merges' coefficients reported), at the start's representative point, where
every elastic family absent at the start and a level base's tilt are at their typical size: a
parameter acting only through them (a vertical base joint's compliance, which carries
gravity's torque only on a tilted base) is judged as the data see it once they are there.
With a known noise std, near aliases of the earlier families are merged too, at the start and
again at the optimum.

Fit. Levenberg-Marquardt with the analytic Jacobian (then trust-region reflective under the
physical bounds when its optimum is past one), at most :data:`MAX_EVALUATIONS` evaluations
(a fit stopped there is reported ``converged: false``: an ill-conditioned fit crawls for
thousands: a 57-parameter geometry fit on 30 poses, or a lumped gravity fit whose trial steps
keep meeting a diverging sag); covariance ``sigma^2 (J^T J)^-1`` with the declared noise, or
the residual variance when the campaign declares none; 95 % intervals from the normal quantile
(Student's t over the fit's degrees of freedom when the noise is not declared or the loss is
robust), as deflection campaigns' (:class:`stiffness.calibration.selection.Noise`).

Robust losses (``loss`` of :data:`~stiffness.calibration.solver.LOSSES` other than
``linear``): the deflection engine's mathematics, not a copy of it. The fit minimises
``sum s^2 rho((r / s)^2)`` of the residual components ``r`` (m) by the trust-region reflective
method from the least-squares optimum, ``s`` the noise std: the declared one, else a robust
estimate
(:func:`~stiffness.calibration.outliers.robust_rounds`: of a least-squares fit's residuals,
then of the loss fit's, as both deflection commands do), its steps on the factor of the
loss-reweighted Jacobian over blocks of rows (:meth:`PoseProblem.robust_factor`), as least
squares' on that of ``[r, J]``. The covariance is Huber's sandwich
(:func:`~stiffness.calibration.solver.sandwich_matrix`, on the factor of ``J``), and
:meth:`PoseFit.loss_rss` (the loss sum over its Gaussian expectation,
:func:`~stiffness.calibration.solver.gaussian_loss_mean`) stands for the residual sum of
squares in BIC, so an outlier adds about ``2 s |r|`` instead of ``r^2``; the fit-to-noise
test leaves the poses flagged as outliers out instead (:func:`noise_terms`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg
from scipy.optimize import lsq_linear

from stiffness.calibration import solver
from stiffness.calibration.identifiability import (
    NEAR_ALIAS_RESOLUTION,
    Identifiability,
    Layout,
    stacked_triangular,
    triangular,
)
from stiffness.calibration.outliers import Outlier, flag_residuals, leverage, robust_rounds
from stiffness.calibration.pose_campaign import PoseCampaign
from stiffness.calibration.pose_model import PoseModel, PoseModelError, align_frames
from stiffness.calibration.pose_orientation import PoseObservations
from stiffness.calibration.selection import (
    Noise,
    NoiseTerms,
    bounded_intervals,
    kept_terms,
)
from stiffness.calibration.solver import (
    Options,
    Solution,
    check_loss,
    covariance_matrix,
    loss_terms,
    objective_rss,
)
from stiffness.cores import one_blas_thread
from stiffness.elastic.effects.base import Held
from stiffness.elastic.effects.pose_face import RowTerms
from stiffness.errors import ConvergenceError, StiffnessError, TooFewMeasurementsError

#: Residual (m, each component) of a trial step whose sag does not converge (an unphysically
#: large compliance): far above any measured error, so the solver refuses the step.
DIVERGED_RESIDUAL_M = 1.0
#: Evaluations of the model after which a fit stops (not converged).
MAX_EVALUATIONS = 200
#: Smallest ``1 - leverage`` of a configuration's components for :func:`held_out_rms` (below
#: it, leaving the configuration out leaves a direction of the parameters undetermined).
LEVERAGE_TOL = 1e-9
#: Configurations :func:`held_out_rms` treats as one array (bounds its memory: their rows of
#: the Jacobian and hat blocks).
HELD_OUT_BLOCK = 1024
#: Largest deletion step (in typical sizes of a parameter) :func:`held_out_rms` takes to
#: first order; a configuration whose step is larger is predicted by the model itself.
HELD_OUT_LINEAR_STEPS = 10.0


def rows_of(model: PoseModel, campaign: PoseCampaign) -> list[RowTerms]:
    """The parameter-independent terms of every row of ``campaign``."""
    wrench = None if campaign.loads is None else campaign.loads.wrench
    return [model.row_terms(q, None if wrench is None else wrench[i])
            for i, q in enumerate(campaign.configurations)]


def campaign_settings(campaign: PoseCampaign) -> dict:
    """The families' fixed settings from ``campaign`` (:meth:`PoseModel.campaign_settings`:
    the backlash smoothing torques), to build its models with."""
    nominal = PoseModel(campaign.robot, campaign.markers, (), (np.eye(3), np.zeros(3)),
                        campaign.loads)
    return nominal.campaign_settings(rows_of(nominal, campaign))


def starting_frame(campaign: PoseCampaign) -> tuple[np.ndarray, np.ndarray]:
    """The measuring frame that best aligns the nominal robot's markers with the measurements."""
    nominal = PoseModel(campaign.robot, campaign.markers, (), (np.eye(3), np.zeros(3)))
    y, _ = nominal.evaluate(np.zeros(0), rows_of(nominal, campaign), jacobian=False)
    try:
        return align_frames(y.reshape(-1, 3), campaign.positions.reshape(-1, 3))
    except PoseModelError as exc:  # one pose of one marker: say what the campaign holds
        seen = int(np.all(np.isfinite(campaign.positions), axis=2).sum())
        where = "" if campaign.path is None else f"{campaign.path}: "
        raise PoseModelError(
            f"{where}{campaign.n_rows} pose(s) of {len(campaign.markers)} marker(s), "
            f"{seen} marker position(s) seen: the measuring frame needs three seen positions "
            "not in one line; measure more poses (or markers), varied") from exc


@dataclass
class PoseFit:
    """A fitted pose model.

    Attributes
    ----------
    model
        The model (families, markers, starting frame).
    x
        (p,) parameters, SI; zero where not fitted.
    identifiability
        The fitted (kept) and dropped parameters.
    covariance
        (k, k) covariance of the kept parameters (order of ``identifiability.kept``), none
        of them held, those at their bound neither: a deflection fit's
        (:func:`~stiffness.calibration.fitting.compliance_covariance`), whose diagonal gives
        :meth:`std`; only an interval's end holds bound parameters
        (:func:`~stiffness.calibration.selection.end_covariances`).
    residual
        (n, M, 3) measured minus predicted (m); NaN where a marker was not seen.
    noise
        The noise of its intervals (:class:`~stiffness.calibration.selection.Noise`): the
        standard deviation used for the covariance (m, :attr:`sigma`; a robust fit's loss
        scale) and whether it is declared or estimated, with its quantiles.
    sigma_source
        ``"declared"``, ``"residual"`` (least squares' residual variance) or ``"robust"``
        (the robust estimate scaling a robust loss).
    loss
        The loss the fit minimised (:data:`~stiffness.calibration.solver.LOSSES`).
    converged
        Whether the solver met its tolerances within :data:`MAX_EVALUATIONS` evaluations.
    rotation_residual
        (n, M, 3) measured minus predicted orientations (rad, rotation vectors in measuring
        axes; NaN where not measured), or ``None`` for a campaign without them.
    rotation_weight
        ``sigma_t / sigma_r`` (m/rad) the orientations were weighted by
        (:mod:`stiffness.calibration.pose_orientation`), or ``None``.
    factor
        (m, k) a matrix whose ``F^T F`` is ``J^T J`` for ``J`` the (N, k) d(residual
        components)/d(kept parameters) at the optimum (the solver's factor, never ``J``
        itself: a large campaign's Jacobian is not kept): the held-out criterion's hat
        matrix (:func:`held_out_rms`) and the leverages (:func:`flag_pose_outliers`).
    observations
        What the fit compared: ``J``'s rows are evaluated again from it at ``x``, a block
        at a time.
    """

    model: PoseModel
    x: np.ndarray
    identifiability: Identifiability
    covariance: np.ndarray
    residual: np.ndarray
    noise: Noise
    sigma_source: str
    extras: dict = field(default_factory=dict)
    loss: str = "linear"
    converged: bool = True
    rotation_residual: np.ndarray | None = None
    rotation_weight: float | None = None
    factor: np.ndarray | None = None
    observations: PoseObservations | None = None
    at_bound: list[int] = field(default_factory=list)

    @property
    def sigma(self) -> float:
        """Noise standard deviation used for the covariance (m); a robust fit's loss scale."""
        return self.noise.sigma

    def components(self) -> np.ndarray:
        """The residual components as fitted: positions (m), then the weighted orientations
        (m, position-noise units)."""
        r = self.residual[np.isfinite(self.residual)]
        if self.rotation_residual is None or self.rotation_weight is None:
            return r
        rot = self.rotation_residual[np.isfinite(self.rotation_residual)]
        return np.concatenate([r, self.rotation_weight * rot])

    @property
    def n_observed(self) -> int:
        """Number of measured components (positions and orientations)."""
        return int(self.components().size)

    @property
    def n_fitted(self) -> int:
        """Number of fitted parameters."""
        return len(self.identifiability.kept)

    def row_residuals(self) -> np.ndarray:
        """Each pose's residual components, predicted minus measured: (n, 3 M) positions (m),
        then with orientations their (n, 3 M) weighted into position-noise units, NaN where
        not seen (the CSV's columns, ``<marker>_x`` ... ``<marker>_rz``): the rows
        :func:`flag_pose_outliers` flags and the fit-to-noise test reads
        (:func:`noise_terms`)."""
        n = self.residual.shape[0]
        parts = [-self.residual.reshape(n, -1)]
        if self.rotation_residual is not None and self.rotation_weight is not None:
            parts.append(-self.rotation_weight * self.rotation_residual.reshape(n, -1))
        return np.hstack(parts)

    def rss(self) -> float:
        """Sum of squared residual components (m^2; orientations weighted)."""
        r = self.components()
        return float(r @ r)

    def rms(self) -> float:
        """RMS of the residual components (m; orientations weighted into position-noise
        units)."""
        return float(np.sqrt(self.rss() / max(self.n_observed, 1)))

    def loss_rss(self) -> float:
        """The minimised objective as a sum of squares (m^2): :meth:`rss` for least squares;
        for a robust loss ``sigma^2 sum rho((r / sigma)^2)`` over its Gaussian expectation
        (:func:`~stiffness.calibration.solver.objective_rss`)."""
        return objective_rss(self.components(), self.loss, self.sigma)

    def terms(self) -> tuple[float, int]:
        """:meth:`loss_rss` (m^2) and :attr:`n_fitted` (:meth:`search.Fitted.terms`)."""
        return self.loss_rss(), self.n_fitted

    def labels(self) -> list[str]:
        """Each column of :attr:`x` named (its parameter's label)."""
        return [p.label for p in self.model.parameters]

    def additions(self) -> tuple[str, ...]:
        """The model's families (those of the baseline too: no step adds them)."""
        return self.model.families

    def std(self) -> np.ndarray:
        """(p,) standard deviations; NaN for parameters not fitted. Those of :attr:`covariance`,
        none held, also beside parameters at their bound: the standard error both campaign
        kinds print beside an interval (:func:`~stiffness.calibration.selection.
        end_covariances`)."""
        out = np.full(self.model.size, np.nan)
        out[self.identifiability.kept] = np.sqrt(np.diag(self.covariance))
        return out

    def interval(self) -> tuple[np.ndarray, np.ndarray]:
        """95 % intervals (p,) each; NaN for parameters not fitted (the quantiles of
        :attr:`noise`), none
        below a parameter's physical lower bound. A parameter at its bound
        (:attr:`at_bound`) has the one-sided interval from the bound to its 95 % upper
        limit. Each end of the others' holds only those that moving the parameter that way
        would take past their bound
        (:func:`~stiffness.calibration.selection.bounded_intervals` on :attr:`covariance`)."""
        lower = np.array([p.lower for p in self.model.parameters])
        kept = self.identifiability.kept
        lo, hi = np.full(self.model.size, np.nan), np.full(self.model.size, np.nan)
        lo[kept], hi[kept] = bounded_intervals(
            self.x[kept], lower[kept], self.covariance, [kept.index(i) for i in self.at_bound],
            self.noise.two_sided(), self.noise.one_sided())
        return lo, hi


def layout(model: PoseModel, order: list[str]) -> Layout:
    """How identifiability judges ``model``'s parameters
    (:class:`~stiffness.calibration.identifiability.Layout`): one group per family in
    ``order``, each parameter's typical size :attr:`FamilyParameter.scale` (at or above its
    lower bound at the representative point), and the families whose zero is an absent effect
    (:attr:`PoseFamily.absent_at_zero`: the elastic ones and the base tilt) present at their
    typical size there."""
    sl = model.slices()
    groups = [list(range(sl[f].start, sl[f].stop)) for f in order]
    absent = {f.name for f in model.family_objects if f.absent_at_zero}
    return Layout(groups, [True] * len(groups),
                  np.array([p.scale for p in model.parameters]),
                  np.array([max(p.scale, p.lower) for p in model.parameters]),
                  [(g, g) for f, g in zip(order, groups, strict=True) if f in absent])


@one_blas_thread
def linearised_rss(model: PoseModel, campaign: PoseCampaign, rows: list[RowTerms],
                   order: list[str], x0: np.ndarray, loss: str = "linear",
                   sigma: float = 1.0, held: Sequence[int] = ()) -> tuple[float, int, int]:
    """One Gauss-Newton step from ``x0``: the objective it reaches (:func:`objective_rss`
    under ``loss`` scaled by ``sigma``, m^2, comparable with the fit's
    :meth:`PoseFit.loss_rss`), the number of identifiable parameters and how many of them
    are the last family of ``order``'s (0: it adds none, it moves no marker beyond what the
    others do; the parameters ``held``, model columns, stay at ``x0`` and are not counted).
    From a fit of some of ``model``'s families (``x0`` its optimum, zero for the others),
    this is the score-test screen of adding the others: what their columns explain of the
    residual beyond the fitted ones, to first order (infinite where the sag diverges at
    ``x0``)."""
    obs = PoseObservations(model, campaign, rows)
    plan = layout(model, order)
    try:  # the residual and the Jacobian through their factor R (observed_factor)
        tri, weighted = _screen_factors(obs, x0, loss, sigma)
    except ConvergenceError:
        return math.inf, 0, 0
    # held after the reduction, as the fit holds them: what merges into a held one stays out
    held_set = set(held)
    kept = [k for k in plan.reduce(tri[:, 1:] * plan.scales).kept if k not in held_set]
    last = model.slices()[order[-1]]
    fresh = sum(last.start <= k < last.stop for k in kept)
    # |r - J_kept s| = |R_r - R_kept s| for every s: the least squares on the factor
    scales = plan.scales[kept]  # the step in typical sizes: lstsq's cut-off is relative
    columns = weighted[:, [1 + c for c in kept]] * scales
    # the parameters move by -step * scales, never past their physical bounds (a compliance
    # below 0: the bounded fit cannot follow, and a family screened so took others' fits)
    room = (x0[kept] - np.array([p.lower for p in model.parameters])[kept]) / scales
    if np.isfinite(room).any():
        step = lsq_linear(columns, weighted[:, 0], bounds=(-np.inf, room), method="bvls").x
    else:
        step, *_ = np.linalg.lstsq(columns, weighted[:, 0], rcond=None)
    if loss == "linear":
        left = tri[:, 0] - columns @ step
        return float(left @ left), len(kept), fresh
    after = np.empty(obs.size)  # a robust loss needs the residuals: a second pass
    for index, r, j in obs.blocks(x0):
        after[index] = r - (j[:, kept] * scales) @ step
    return objective_rss(after, loss, sigma), len(kept), fresh


def _screen_factors(obs: PoseObservations, x: np.ndarray, loss: str, sigma: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The factors ``R`` of ``[r, J]`` at ``x`` (:func:`observed_factor`: what the identifiable
    reduction reads) and of the same rows weighted for ``loss``'s Gauss-Newton step, each row
    by ``sqrt(rho'((r / sigma)^2))`` at the residuals of ``x`` (iteratively reweighted least
    squares: at a robust optimum the step is nil, where least squares' chases the outliers;
    FIGAROH's TIAGo, ghost markers 0.2-1 m off, screened every family 400-600 worse in BIC
    than the robust baseline). For least squares both are the one factor.

    Raises
    ------
    ConvergenceError
        The sag diverges at ``x``.
    """
    if loss == "linear":
        tri = observed_factor(obs, x)
        return tri, tri
    k = obs.model.size + 1
    plain, weighted = np.zeros((0, k)), np.zeros((0, k))
    for _, r, j in obs.blocks(x):
        block = np.column_stack([r, j])
        root = np.sqrt(loss_terms(loss, (r / sigma) ** 2)[1])
        plain = stacked_triangular([plain, block], k)
        weighted = stacked_triangular([weighted, block * root[:, None]], k)
    return plain, weighted


def held_out_rms(fit: PoseFit, campaign: PoseCampaign,
                 progress: Callable[[int, int], None] | None = None) -> float:
    """Leave-one-configuration-out RMS of the position residual (m) without refitting: each
    configuration predicted by the parameters the fit would reach without it, to first order.

    With ``J`` the fit's Jacobian over its kept parameters at the optimum (full column rank
    by the identifiable reduction; a parameter at its physical bound held there: its column
    left out) and ``r`` its residual, leaving configuration
    ``G``'s components out moves the parameters by ``dx_G = R^-1 Q_G^T (I - H_G)^-1 r_G``
    (``J = Q R``, ``H_G = Q_G Q_G^T`` the hat matrix's block of ``G``: the deletion formula,
    exact for a model linear in its parameters, the refit's Gauss-Newton step otherwise), and
    ``G``'s residual there is, to first order, ``r_G - J_G dx_G = (I - H_G)^-1 r_G`` (PRESS).
    A configuration whose step moves a parameter by more than :data:`HELD_OUT_LINEAR_STEPS`
    of its typical sizes is predicted by the model itself at ``x - dx_G`` instead: its sag
    and geometry in full, so a fit whose neighbours sag without bound there is caught. The
    criterion is ``sqrt(objective / n)`` of the held-out position components
    (:func:`objective_rss` under the fit's loss and scale: their sum of squares for least
    squares). Infinite when a configuration alone determines a direction of the parameters
    (its leverage reaches 1 within :data:`LEVERAGE_TOL`) or the sag diverges at a
    configuration's shifted parameters: the campaign cannot validate those parameters.

    ``R`` comes from the fit's factor (:attr:`PoseFit.factor`), then the configurations'
    blocks ``H_G`` and solves are stacked arrays, :data:`HELD_OUT_BLOCK` configurations at a
    time, their rows of ``J`` evaluated again at the optimum (memory bounded: ``J`` is never
    held whole), and the far steps' predictions.

    Parameters
    ----------
    campaign
        The campaign the fit was made on: rows sharing a configuration label are left out
        together.
    progress
        Called with (configurations done, configurations) after each block of them (a
        progress bar), or ``None``.
    """
    obs = fit.observations
    if fit.factor is None or obs is None:
        raise StiffnessError("this fit keeps no Jacobian; fit it with fit_pose_model")
    rows = obs.component_rows()
    r = fit.components()
    free = [c for c, i in enumerate(fit.identifiability.kept) if i not in fit.at_bound]
    kept = [fit.identifiability.kept[c] for c in free]
    scale = np.array([fit.model.parameters[i].scale for i in kept])
    tri = triangular(fit.factor, free)
    _, label_group = np.unique(np.asarray(campaign.labels), return_inverse=True)
    label_group = label_group.ravel()
    members = _padded(label_group[rows])  # each configuration's components, -1 padded
    positions = int(np.isfinite(fit.residual).sum())
    held, far = [], []
    for start in range(0, members.shape[0], HELD_OUT_BLOCK):
        block = members[start:start + HELD_OUT_BLOCK]
        index = np.unique(block[block >= 0])
        try:
            jac = obs.jacobian_rows(fit.x, index)[:, kept]
        except ConvergenceError:  # the sag diverges at the optimum: not a fit to choose
            return math.inf
        deleted = _deletion(jac, tri, r[index],
                            np.where(block >= 0, np.searchsorted(index, block), -1))
        if deleted is None:
            return math.inf
        press, step = deleted
        near = np.max(np.abs(step) / scale, axis=1, initial=0.0) <= HELD_OUT_LINEAR_STEPS
        held.append(press[(block >= 0) & (block < positions) & near[:, None]])
        far += [(np.flatnonzero(label_group == label_group[rows[block[b, 0]]]), step[b])
                for b in np.flatnonzero(~near)]
        if progress is not None:
            progress(start + block.shape[0], members.shape[0])
    for config_rows, step in far:
        x = fit.x.copy()
        x[kept] -= step
        part = campaign.subset(config_rows)
        obs = PoseObservations(fit.model, part, rows_of(fit.model, part))
        try:
            e, _ = obs.evaluate(x, jacobian=False)
        except ConvergenceError:
            return math.inf
        held.append(e[:int(obs.observed.sum())])
    errors = np.concatenate(held) if held else np.zeros(0)
    return math.sqrt(objective_rss(errors, fit.loss, fit.sigma) / max(errors.size, 1))


def _deletion(jac: np.ndarray, tri: np.ndarray, r: np.ndarray, block: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """For each configuration of ``block`` (its components' indices into ``jac``'s rows and
    ``r``, -1 padded), the PRESS residual ``(I - H_G)^-1 r_G`` (padded like ``block``, zero
    at the padding) and the deletion step ``dx_G`` (k,) (:func:`held_out_rms`; the fit's
    Jacobian ``J = Q tri``, ``jac`` some of its rows); ``None`` when a leverage reaches 1
    within :data:`LEVERAGE_TOL`."""
    pad = block < 0
    index = np.where(pad, 0, block)
    # Q_G = J_G R^-1, zero rows at the padding (where I - H_G is then 1)
    qg = linalg.solve_triangular(tri, jac[index.ravel()].T, trans="T").T
    qg = qg.reshape(block.shape + (tri.shape[0],)) * ~pad[..., None]
    a = np.eye(block.shape[1]) - qg @ np.swapaxes(qg, 1, 2)
    if np.linalg.eigvalsh(a)[:, 0].min(initial=1.0) < LEVERAGE_TOL:
        return None
    press = np.linalg.solve(a, np.where(pad, 0.0, r[index])[..., None])
    step = linalg.solve_triangular(tri, (np.swapaxes(qg, 1, 2) @ press)[..., 0].T).T
    return press[..., 0], step


def _padded(group: np.ndarray) -> np.ndarray:
    """(groups, largest size) indices of each group's items (``group``: each item's group
    number), ascending, padded with -1."""
    index = np.argsort(group, kind="stable")
    sizes = np.bincount(group)
    sizes = sizes[sizes > 0]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
    out = np.full((sizes.size, int(sizes.max(initial=0))), -1)
    for column in range(out.shape[1]):
        has = sizes > column
        out[has, column] = index[starts[has] + column]
    return out


@one_blas_thread
def fit_pose_model(model: PoseModel, campaign: PoseCampaign, rows: list[RowTerms],
                   order: list[str], x0: np.ndarray | None = None, loss: str = "linear",
                   scale: float | None = None, held: dict[int, Held] | None = None
                   ) -> PoseFit:
    """Fit the identifiable parameters of ``model`` to ``campaign``.

    Parameters
    ----------
    order
        The model's families in the order they were chosen (earlier families keep the
        directions they share with later ones).
    x0
        Starting parameters (p,), default zero. A start whose sag diverges once the parameters
        this campaign cannot identify are zeroed (a warm start from a fit on other rows) falls
        back to zero.
    loss
        ``linear`` (least squares) or a robust loss of
        :data:`~stiffness.calibration.solver.LOSSES` (module docstring).
    scale
        Noise std (m) scaling a robust loss; default the campaign's declared noise, else the
        robust estimate (module docstring). Ignored by least squares.
    held
        Parameters (model columns) held at zero, their nominal value, with why: not fitted,
        reported ``undetermined`` with that note (:func:`stiffness.calibration.naming.settle`).

    Raises
    ------
    StiffnessError
        Fewer measured components than identifiable parameters, or an unknown loss.
    """
    check_loss(loss)
    if loss != "linear" and scale is None and campaign.noise_std is None:
        return _fit_robust_scale(model, campaign, rows, order, x0, loss, held)
    x = np.zeros(model.size) if x0 is None else np.array(x0, dtype=float)
    obs = PoseObservations(model, campaign, rows)
    noise = scale if scale is not None else campaign.noise_std
    problem = PoseProblem(obs, order, noise)
    if problem.failed(x):
        x[:] = 0.0
    options = Options("lm", 1e-12, MAX_EVALUATIONS, problem.layout.scales)
    # near aliases judged at the start too: off the rigid arm the model's first-order
    # Jacobian tells apart, by a sine of 1e-5, parameters the data cannot (a base joint's zero
    # offset and the measuring frame's rotation), which would cost every fit a second one
    sol = solver.fit(problem, x, options, NEAR_ALIAS_RESOLUTION if noise else 0.0, held,
                     near_at_start=True)
    if loss == "linear":
        return _finish(obs, campaign, sol, sol.jac, sol.fun)
    assert noise is not None  # undeclared noise and no scale: _fit_robust_scale estimated it
    # from the least-squares optimum: a few steps (from far, every residual is beyond the
    # loss's scale and the robust steps crawl), and a start for cauchy's non-convex loss
    options.method, options.loss, options.f_scale = "trf", loss, noise
    sol = solver.solve(problem, sol.x, sol.identifiability, options)
    # the solver's factor is of the Jacobian reweighted by the loss: the plain Jacobian's at
    # the optimum instead (the sandwich needs only its J^T J); where the sag diverges there
    # the residual is the diverged constant (the fit is not chosen) and the solver's factor
    # stands in, as least squares' does
    fun = problem.fun(sol.x)
    jac = (sol.jac if problem.failed(sol.x)
           else problem.factor(sol.x, np.asarray(sol.identifiability.kept))[:, 1:])
    source = "declared" if scale is None or scale == campaign.noise_std else "robust"
    return _finish(obs, campaign, sol, jac, fun, loss, (noise, source))


def observed_factor(obs: PoseObservations, x: np.ndarray) -> np.ndarray:
    """``R`` (at most (p + 1, p + 1)) of ``[r, J] = Q R`` at ``x``: ``obs``'s residuals and
    Jacobian, by QR of blocks of rows stacked
    (:func:`~stiffness.calibration.identifiability.stacked_triangular`): a large campaign's
    Jacobian is never held whole.

    Raises
    ------
    ConvergenceError
        The sag diverges at ``x``.
    """
    return stacked_triangular((np.column_stack([r, j]) for _, r, j in obs.blocks(x)),
                              obs.model.size + 1)


class PoseProblem:
    """A pose campaign's observation (:class:`stiffness.calibration.solver.Problem`):
    predicted minus measured components (m; orientations weighted) of ``obs`` and their
    Jacobian over the model's parameters, the families laid out in ``order``
    (:func:`layout`), the columns whitened by ``noise`` (m) when known; a parameter left out
    is held at zero, its nominal value, and a start whose sag diverges so falls back to
    zero."""

    def __init__(self, obs: PoseObservations, order: list[str], noise: float | None) -> None:
        self.obs, self.noise = obs, noise
        self.layout = layout(obs.model, order)
        #: every parameter's nominal value: zero (the nominal robot, rigid, the measuring
        #: frame at its start)
        self.nominal = np.zeros(obs.model.size)
        self.lower = np.array([p.lower for p in obs.model.parameters])
        self._factor: tuple[np.ndarray, np.ndarray] | None = None

    def fun(self, x: np.ndarray) -> np.ndarray:
        """Predicted minus measured (m); :data:`DIVERGED_RESIDUAL_M` where the sag diverges
        (a trial step refused as a bad one)."""
        try:
            r, _ = self.obs.evaluate(x, jacobian=False)
        except ConvergenceError:
            return np.full(self.obs.size, DIVERGED_RESIDUAL_M)
        return r

    def jac(self, x: np.ndarray) -> np.ndarray:
        """d(residual)/dx (N, p); zero where the sag diverges (the residual there is the
        diverged constant, :meth:`fun`: a bounded refit whose strictly feasible start, just
        inside a bound, lands there stops at once instead of raising)."""
        try:
            _, j = self.obs.evaluate(x)
        except ConvergenceError:
            return np.zeros((self.obs.size, self.obs.model.size))
        assert j is not None
        return j

    def failed(self, x: np.ndarray) -> bool:
        """Whether the sag diverges at ``x``."""
        try:
            self.obs.evaluate(x, jacobian=False)
        except ConvergenceError:
            return True
        return False

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The parameters' physical lower bounds; no upper ones."""
        return self.lower, np.full(self.lower.size, np.inf)

    def factor(self, x: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """``R`` of ``[r, J[:, columns]] = Q R`` at ``x`` (:class:`~stiffness.calibration.
        solver.Factored`), from :func:`observed_factor` (kept for the last ``x``); where the
        sag diverges, that of the diverged constant and a zero Jacobian (as :meth:`jac`)."""
        try:
            whole = self._whole_factor(x)
        except ConvergenceError:
            whole = np.zeros((self.obs.model.size + 1,) * 2)  # |fun(x)|, not evaluated again
            whole[0, 0] = np.linalg.norm(np.full(self.obs.size, DIVERGED_RESIDUAL_M))
        return triangular(whole, [0] + [1 + int(c) for c in columns])

    def robust_factor(self, x: np.ndarray, columns: np.ndarray, scaling: solver.RowScaling
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The residuals (as :meth:`fun`), a robust loss's gradient ``J[:, columns]^T psi``
        and ``R`` of ``diag(w) J[:, columns]`` at ``x``, ``(psi, w) = scaling(r)``
        (:class:`~stiffness.calibration.solver.Factored`), block by block; where the sag
        diverges, the diverged constant and zero (as :meth:`fun` and :meth:`jac`)."""
        residual, gradient = np.empty(self.obs.size), np.zeros(len(columns))

        def rows(index: np.ndarray, r: np.ndarray, j: np.ndarray) -> np.ndarray:
            residual[index] = r
            psi, w = scaling(r)
            gradient[:] += psi @ j[:, columns]
            return w[:, None] * j[:, columns]

        try:
            tri = stacked_triangular((rows(*block) for block in self.obs.blocks(x)),
                                     len(columns))
        except ConvergenceError:
            return (np.full(self.obs.size, DIVERGED_RESIDUAL_M), np.zeros(len(columns)),
                    np.zeros((len(columns),) * 2))
        return residual, gradient, tri

    def _whole_factor(self, x: np.ndarray) -> np.ndarray:
        """:func:`observed_factor` at ``x``, kept for the last ``x``.

        Raises
        ------
        ConvergenceError
            The sag diverges at ``x``.
        """
        if self._factor is None or not np.array_equal(self._factor[0], x):
            self._factor = (np.array(x, dtype=float), observed_factor(self.obs, x))
        return self._factor[1]

    def columns(self, x: np.ndarray, final: bool) -> np.ndarray | None:
        """The regressor at ``x`` times the typical sizes, over the noise std when known: a
        (p + 1, p) matrix with its inner products (``a^T a``), what identifiability uses."""
        try:
            tri = self._whole_factor(x)
        except ConvergenceError:
            return None
        return tri[:, 1:] * (self.layout.scales / (self.noise or 1.0))

    def start(self, x: np.ndarray, ident: Identifiability) -> np.ndarray:
        """``x`` (its parameters left out already at :attr:`nominal`, zero), or all at zero
        where the sag diverges there.

        Raises
        ------
        TooFewMeasurementsError
            Fewer measured components than identifiable parameters.
        """
        if len(ident.kept) >= self.obs.size:
            raise TooFewMeasurementsError(f"{len(ident.kept)} identifiable parameters but only "
                                 f"{self.obs.size} measured components; measure more poses")
        return self.nominal.copy() if self.failed(x) else x


def _fit_robust_scale(model: PoseModel, campaign: PoseCampaign, rows: list[RowTerms],
                      order: list[str], x0: np.ndarray | None, loss: str,
                      held: dict[int, Held] | None = None) -> PoseFit:
    """A robust ``loss`` fit scaled by the robust noise estimate
    (:func:`~stiffness.calibration.outliers.robust_rounds` from a least-squares fit; ``held``
    held throughout)."""
    fit, _ = robust_rounds(
        fit_pose_model(model, campaign, rows, order, x0, held=held),
        lambda fit, s: fit_pose_model(model, campaign, rows, order, fit.x, loss, s, held),
        lambda fit: fit.residual[np.isfinite(fit.residual)], lambda fit: fit.n_fitted,
        loss, lambda fit: max(fit.rms(), 1e-12))
    return fit


def _finish(obs: PoseObservations, campaign: PoseCampaign, sol: Solution, jac: np.ndarray,
            fun: np.ndarray, loss: str = "linear",
            robust_scale: tuple[float, str] | None = None) -> PoseFit:
    """The fit at the solver's optimum ``sol`` from the residuals ``fun`` (predicted minus
    measured, m; orientations weighted) and their Jacobian ``jac`` over the kept parameters
    (or a factor of it with the same ``J^T J``: the solver's, :class:`PoseProblem`);
    ``robust_scale`` the (noise std, source) scaling a robust ``loss``. The covariance is the
    engine's (:func:`~stiffness.calibration.solver.covariance_matrix`, in the parameters'
    typical sizes), of the declared noise, else the residual's (least squares), or the
    sandwich, over every kept parameter, those at their physical bound (``sol.at_bound``) too
    (none held: :attr:`PoseFit.covariance`)."""
    ident = sol.identifiability
    residual, rotation = obs.split(fun)
    n, k = fun.size, len(ident.kept)
    if robust_scale is not None:
        sigma, source = robust_scale
    elif campaign.noise_std is not None:
        sigma, source = campaign.noise_std, "declared"
    else:
        sigma, source = float(np.sqrt(fun @ fun / max(n - k, 1))), "residual"
    sizes = np.array([obs.model.parameters[i].scale for i in ident.kept])
    spread = covariance_matrix(jac * sizes, sigma, loss, fun, sigma)
    # the intervals' noise: declared, else estimated over n - k degrees of freedom (least
    # squares' residuals); a robust loss's sandwich, declared scale or not, over n - d: d the
    # directions the covariance reported spreads over, bound parameters' too (Noise.of_fit)
    noise = (Noise(sigma) if campaign.noise_std is not None else
             Noise.estimated(sigma, n, k)).of_fit(loss, n, spread)
    cov = spread.matrix * np.outer(sizes, sizes)
    return PoseFit(obs.model, sol.x.copy(), ident, cov, residual, noise, source, loss=loss,
                   converged=sol.status > 0, rotation_residual=rotation,
                   rotation_weight=obs.weight,
                   factor=jac if jac.shape[0] <= k + 1 else triangular(jac), observations=obs,
                   at_bound=list(sol.at_bound))


def flag_pose_outliers(fit: PoseFit, campaign: PoseCampaign
                       ) -> tuple[list[Outlier], float | None]:
    """The poses (rows) ``fit`` does not explain, by deflection campaigns' rule
    (:func:`~stiffness.calibration.outliers.flag_residuals`), and the noise std (m) they were
    standardised by.

    Each measured component, predicted minus measured (orientations weighted into
    position-noise units as the fit sees them), over ``sigma sqrt(1 - h)``: ``h`` its leverage
    in the fit's Jacobian, ``sigma`` the declared noise std, else the robust estimate of the
    residuals. A pose is flagged when a component of it exceeds
    :data:`~stiffness.calibration.outliers.OUTLIER_THRESHOLD`; components are named as the
    CSV's columns (``<marker>_x`` ... ``<marker>_rz``).

    Parameters
    ----------
    campaign
        The campaign the fit was made on (its labels and CSV lines name the rows).
    """
    obs = fit.observations
    if fit.factor is None or obs is None:
        raise StiffnessError("this fit keeps no Jacobian; fit it with fit_pose_model")
    h = np.empty(obs.size)  # the Jacobian's rows a block at a time
    for index, _, jac in obs.blocks(fit.x):
        h[index] = leverage(jac[:, fit.identifiability.kept], fit.factor)
    n = fit.residual.shape[0]
    parts: list[tuple[np.ndarray, tuple[str, ...]]] = [(fit.residual, ("x", "y", "z"))]
    if fit.rotation_residual is not None and fit.rotation_weight is not None:
        parts.append((fit.rotation_residual, ("rx", "ry", "rz")))
    lev, names, used = [], [], 0
    for e, axes in parts:  # the leverages in the layout of PoseFit.row_residuals
        seen = np.isfinite(e)
        scattered = np.full(e.shape, np.nan)
        scattered[seen] = h[used:used + int(seen.sum())]
        used += int(seen.sum())
        lev.append(scattered.reshape(n, -1))
        names += [f"{m.name}_{a}" for m in fit.model.markers for a in axes]
    return flag_residuals(fit.row_residuals(), np.hstack(lev), campaign.noise_std,
                          fit.n_fitted, tuple(campaign.labels), campaign.lines, names)


def noise_terms(fit: PoseFit, campaign: PoseCampaign) -> NoiseTerms:
    """:func:`~stiffness.calibration.selection.kept_terms` of a pose ``fit`` on ``campaign``:
    its poses' residual components (:meth:`PoseFit.row_residuals`) and, under a robust loss,
    the poses :func:`flag_pose_outliers` flags left out (standardised by the declared noise
    std, which a fit-to-noise test needs and a robust loss is then scaled by); its whole
    objective tested (no split by kind: a pose campaign's orientation noise is declared)."""
    return kept_terms(fit.row_residuals(), fit.n_fitted, fit.loss,
                      lambda: [o.row - 1 for o in flag_pose_outliers(fit, campaign)[0]])


def predict(model: PoseModel, x: np.ndarray, campaign: PoseCampaign) -> np.ndarray:
    """Predicted positions (n, M, 3) of ``campaign``'s rows (m), measuring frame."""
    y, _ = model.evaluate(x, rows_of(model, campaign), jacobian=False)
    return y
