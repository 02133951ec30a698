"""Rows a fit does not explain: standardised residuals, a robust noise estimate, the flags.

Every fit of ``identify`` and ``diagnose`` flags the rows whose standardised residual exceeds
:data:`OUTLIER_THRESHOLD` (4 standard deviations). A residual component ``e`` (predicted
minus measured; rotations weighted into translation-noise units as the fit sees them) is
standardised as ``e / (sigma sqrt(1 - h))``, ``h`` its leverage (the diagonal of the hat
matrix of the whitened residual Jacobian) and ``sigma`` the declared noise std, else a robust
estimate (:func:`robust_noise`: 1.4826 times the median absolute residual, which a few gross
outliers do not inflate). A row's standardised residual is its component of largest
magnitude. For Gaussian noise a clean component passes 4 with probability 6.3e-5, so a
campaign of 100 rows of three components has a false flag about 2 % of the time. Flags are
reported, never acted on: no row is dropped.

Both campaign kinds flag by this one rule (:func:`flag_residuals`): a deflection campaign's
row is one configuration and load (components ``dx`` ... ``rz``), a pose campaign's one pose
(components ``<marker>_x`` ... ``<marker>_rz``, the CSV's columns, unobserved ones NaN;
:func:`stiffness.calibration.pose_fit.flag_pose_outliers`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from stiffness.calibration.fitting import Fit, fit_model
from stiffness.calibration.solver import SINGULAR_RTOL, loss_terms
from stiffness.elastic.effects.hypothesis import Hypothesis
from stiffness.errors import StiffnessError
from stiffness.htmlpage import esc, num, table

#: A row is flagged when a component's standardised residual exceeds this (noise stds).
OUTLIER_THRESHOLD = 4.0
#: The median absolute deviation of a normal variable times this is its standard deviation.
MAD_TO_STD = 1.482602218505602
#: Largest share of a campaign's rows flagged that are read as stray measurements: a robust
#: loss's fit-to-noise test leaves them out (:func:`stiffness.calibration.selection.
#: kept_terms`); more are a pattern the model misses, kept in the test (a model missing a
#: sizeable effect flags most rows: leaving them out would leave nothing to reject it).
STRAY_SHARE = 0.1
#: Component names of a row's residual, translations then rotations.
COMPONENTS = ("dx", "dy", "dz", "rx", "ry", "rz")
#: Rounds of :func:`robust_rounds`: the scale from a least-squares fit's residuals, then from
#: the loss fit's. Measured (scripts/robust_rounds.py; docs/outliers.md, "Robust losses"): UR5,
#: 18 rows, 3 springs, 20 um undeclared, Huber, 3 components 30 noise stds off, 300 seeds: one
#: round covered 845 of 900 stiffness intervals (sum z^2 / n 1.14), two 847 (1.09), three 845
#: (1.09). Deflection fits (identify, diagnose) go on until the scale settles
#: (:data:`stiffness.calibration.deflection_noise.SCALE_TOLERANCE`); pose fits stop at this.
ROBUST_ROUNDS = 2

_F = TypeVar("_F")


@dataclass(frozen=True)
class Outlier:
    """A flagged row.

    Attributes
    ----------
    label
        Its configuration label.
    row
        1-based row number in the campaign (a pose campaign's row: one pose).
    line
        Its line in the measurement CSV, or ``None`` for a campaign built in memory.
    component
        The component with the largest standardised residual (``dx`` ... ``rz``; on a pose
        campaign ``<marker>_x`` ... ``<marker>_rz``).
    standardised_residual
        That component's standardised residual (signed, noise stds).
    """

    label: str
    row: int
    line: int | None
    component: str
    standardised_residual: float

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {"label": self.label, "row": self.row, "line": self.line,
                "component": self.component,
                "standardised_residual": self.standardised_residual}


def residual_shrinkage(loss: str, standardised: np.ndarray, threshold: float) -> float:
    """``kappa``: the median of the absolute residuals of a fit of ``p`` parameters to ``N``
    components under ``loss`` (soft threshold ``threshold`` noise stds) is ``m0 (1 - kappa p
    / (2 N))`` of the noise's, to first order in ``p / N`` (``m0 = Phi^-1(3/4)``); 1 for
    least squares on Gaussian noise, whose residuals' variance is ``1 - h``.

    An M-fit's residual is ``r_i = e_i - (1/A) sum_j h_ij psi(e_j)`` (``h`` the hat matrix,
    ``psi`` the loss's derivative, ``A = mean psi'``, ``B = mean psi^2``, here over the
    ``standardised`` residuals, noise stds, gross ones included): its own term moves the
    median by ``-h psi(m0) / A``, the others' (variance ``h B / A^2``) by ``+h m0 B /
    (2 A^2)``: ``kappa = 2 psi(m0) / (m0 A) - B / A^2``. A robust loss fits the small
    residuals closer than least squares (``A < 1``): soft_l1 at 1 noise std has ``kappa``
    1.86 on Gaussian noise."""
    def psi(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = (x / threshold) ** 2
        _, d_rho, dd_rho = loss_terms(loss, z)
        return d_rho * x, d_rho + 2.0 * z * dd_rho

    m0 = 1.0 / MAD_TO_STD
    p, dp = psi(np.asarray(standardised, dtype=float))
    a, b = float(np.mean(dp)), float(np.mean(p ** 2))
    return 2.0 * float(psi(np.array([m0]))[0][0]) / (m0 * a) - b / a ** 2


#: The robust fit's first-order shrinkage factor ``1 - (kappa - 1) p / (2 N)``
#: (:func:`robust_noise`) is kept within ``[SHRINKAGE_BOUND, 1 / SHRINKAGE_BOUND]``: beyond,
#: the first order is no answer. Gross rows far beyond a loss scaled far above the noise make
#: ``kappa`` hugely negative (their ``psi^2``, the threshold squared, in ``B``): a UR5
#: campaign of 36 components, two rows moved by 1000 noise stds, under soft_l1 scaled by 23
#: noise stds, read 0.04 noise std unbounded, 0.96 bounded.
SHRINKAGE_BOUND = 0.5


def robust_noise(residuals: np.ndarray, n_parameters: int, loss: str = "linear",
                 f_scale_m: float | None = None) -> float | None:
    """Noise std from residuals (m) that may hold gross outliers: ``1.4826 median |e|`` times
    ``sqrt(N / (N - p))`` for the ``p`` parameters of the fit that left them (least squares'
    shrinkage of its residuals), and for a fit under a robust ``loss`` with soft threshold
    ``f_scale_m`` (m) by ``1 / (1 - (kappa - 1) p / (2 N))`` too, the median's further
    shrinkage (:func:`residual_shrinkage` of the residuals over the estimate; that factor
    within :data:`SHRINKAGE_BOUND` and its inverse); ``None`` without degrees of freedom or
    when every residual is zero."""
    e = np.abs(np.asarray(residuals, dtype=float).reshape(-1))
    n = e.size
    if n <= n_parameters:
        return None
    least_squares = MAD_TO_STD * float(np.median(e)) * math.sqrt(n / (n - n_parameters))
    value = least_squares
    if loss != "linear" and f_scale_m is not None and value > 0:
        for _ in range(3):  # kappa at the estimate itself: a fixed point
            kappa = residual_shrinkage(loss, e / value, f_scale_m / value)
            factor = 1.0 - (kappa - 1.0) * n_parameters / (2.0 * n)
            value = least_squares / min(max(factor, SHRINKAGE_BOUND), 1.0 / SHRINKAGE_BOUND)
    return value if value > 0 else None


def robust_rounds(fit: _F, refit: Callable[[_F, float], _F],
                  residuals: Callable[[_F], np.ndarray], n_parameters: Callable[[_F], int],
                  loss: str, fallback: Callable[[_F], float] | None = None,
                  settle: tuple[float, int] | None = None) -> tuple[_F, float | None]:
    """A robust loss's noise scale, the one rule of both campaign kinds, identify's and
    diagnose's: :data:`ROBUST_ROUNDS` times, :func:`robust_noise` of the ``residuals`` (m) of
    ``fit`` (least squares the first time, then under ``loss`` scaled by the last estimate)
    over its ``n_parameters``, then ``fit`` refitted under the loss scaled by it (``refit``);
    with ``settle = (tolerance, most)`` further rounds until one moves the scale by at most
    ``tolerance`` of it (at most ``most`` rounds in all). ``fallback`` gives the scale where
    the residuals give none (all zero); without it the rounds stop there. Returns the last fit
    and scale (m; ``None``: none)."""
    sigma = None
    fitted: tuple[str, float | None] = ("linear", None)
    tolerance, most = settle if settle is not None else (math.inf, ROBUST_ROUNDS)
    for done in range(max(most, ROBUST_ROUNDS)):
        previous = sigma
        sigma = robust_noise(residuals(fit), n_parameters(fit), *fitted)
        if sigma is None and fallback is not None:
            sigma = fallback(fit)
        if sigma is None:
            return fit, None
        fit, fitted = refit(fit, sigma), (loss, sigma)
        if done + 1 >= ROBUST_ROUNDS and previous is not None and math.isclose(
                sigma, previous, rel_tol=tolerance):
            break
    return fit, sigma


def leverage(jacobian: np.ndarray, factor: np.ndarray | None = None) -> np.ndarray:
    """(N,) diagonal of the hat matrix ``J (J^T J)^+ J^T`` of a residual Jacobian (N, p),
    over its determined directions (singular values above ``SINGULAR_RTOL`` of the
    largest): ``|J V_d S_d^-1|^2`` per row, from the SVD ``U S V^T`` of ``J``, or of
    ``factor`` (any (m, p) matrix with the same ``J^T J``: ``jacobian`` may then be some of
    ``J``'s rows only)."""
    if jacobian.size == 0:
        return np.zeros(jacobian.shape[0])
    _, s, vt = np.linalg.svd(jacobian if factor is None else factor, full_matrices=False)
    keep = s > SINGULAR_RTOL * s.max() if s.size and s.max() > 0 else np.zeros(s.size, bool)
    return np.sum((jacobian @ (vt[keep].T / s[keep])) ** 2, axis=1)


def _standardise(residuals: np.ndarray, h: np.ndarray, sigma: float) -> np.ndarray:
    """``residuals / (sigma sqrt(1 - h))`` (``1 - h`` floored at 1e-6)."""
    return residuals / (sigma * np.sqrt(np.maximum(1.0 - h, 1e-6)))


def flag_outliers(standardised: np.ndarray, labels: tuple[str, ...],
                  lines: tuple[int, ...] | None,
                  threshold: float = OUTLIER_THRESHOLD,
                  names: Sequence[str] = COMPONENTS) -> list[Outlier]:
    """The rows of ``standardised`` (m, k; NaN where a component was not observed) with a
    component beyond ``threshold`` in magnitude, in row order; ``names`` the k columns'."""
    z = np.asarray(standardised, dtype=float)
    size = np.where(np.isfinite(z), np.abs(z), 0.0)
    out = []
    for i in np.flatnonzero(np.max(size, axis=1, initial=0.0) > threshold):
        j = int(np.argmax(size[i]))
        out.append(Outlier(labels[i], int(i) + 1, None if lines is None else int(lines[i]),
                           names[j], float(z[i, j])))
    return out


def flag_residuals(residuals: np.ndarray, h: np.ndarray, declared_m: float | None,
                   n_parameters: int, labels: tuple[str, ...], lines: tuple[int, ...] | None,
                   names: Sequence[str] = COMPONENTS) -> tuple[list[Outlier], float | None]:
    """The rows beyond :data:`OUTLIER_THRESHOLD`, and the noise std (m) they were
    standardised by: the declared ``declared_m``, else :func:`robust_noise` of the observed
    residuals (``None``, with no flags, when every residual is zero). The rule of both
    campaign kinds.

    Parameters
    ----------
    residuals
        (m, k) predicted minus measured (m; rotations weighted into translation-noise units),
        NaN where not observed.
    h
        (m, k) leverage of each component (:func:`leverage` of the fit's Jacobian).
    n_parameters
        Parameters fitted (the robust noise's degrees of freedom).
    labels, lines
        Configuration label and CSV line (or ``None``) of each row.
    names
        The k components' names.
    """
    e = np.asarray(residuals, dtype=float)
    sigma = declared_m if declared_m is not None else robust_noise(e[np.isfinite(e)],
                                                                   n_parameters)
    if sigma is None:
        return [], None
    return flag_outliers(_standardise(e, h, sigma), labels, lines, names=names), sigma


def flag_fit(fit: Fit, measured: np.ndarray, declared_m: float | None, n_parameters: int,
             labels: tuple[str, ...], lines: tuple[int, ...] | None
             ) -> tuple[list[Outlier], float | None]:
    """:func:`flag_residuals` of a deflection fit (``measured``: its observations, m)."""
    residual = fit.predicted - measured
    return flag_residuals(residual, leverage(fit.jacobian).reshape(residual.shape), declared_m,
                          n_parameters, labels, lines)


def outlier_keys(outliers: list[Outlier], sigma_m: float | None) -> dict:
    """``outlier_threshold``, ``outlier_sigma_m`` (the noise std the residuals were
    standardised by, m) and ``outliers``, as an identification's ``--json`` has them."""
    return {"outlier_threshold": OUTLIER_THRESHOLD, "outlier_sigma_m": sigma_m,
            "outliers": [o.to_dict() for o in outliers]}


def describe_outliers(outliers: list[Outlier], threshold: float = OUTLIER_THRESHOLD,
                      limit: int = 12) -> list[str]:
    """Text lines of a report: the threshold, then one line per flagged row (at most
    ``limit``)."""
    head = (f"outliers (|standardised residual| > {threshold:g} noise std; flagged, not "
            f"dropped): ")
    if not outliers:
        return [head + "none"]
    lines = [head + f"{len(outliers)} row(s)"]
    for o in outliers[:limit]:
        where = f"row {o.row}" + ("" if o.line is None else f" (line {o.line})")
        lines.append(f"  config {o.label} {where}: {o.component} "
                     f"{o.standardised_residual:+.3g} sigma")
    if len(outliers) > limit:
        lines.append(f"  ... and {len(outliers) - limit} more (see --json)")
    return lines


def outliers_section(d: dict) -> list[str]:
    """The rows beyond the outlier threshold (flagged, none dropped): the section of both
    campaign kinds' pages, from their ``outlier_threshold``, ``outliers`` and ``loss`` keys."""
    threshold = d.get("outlier_threshold")
    intro = (f"<p>Rows of the final model whose standardised residual (residual over the "
             f"noise std and its leverage) exceeds {num(threshold)} in some component; "
             f"flagged only: every row stays in the fit (loss: {esc(d.get('loss', 'linear'))})."
             "</p>")
    flagged = d.get("outliers", [])
    if not flagged:
        return [intro, "<p>None.</p>"]
    rows = [[esc(o["label"]), o["row"], o["line"] if o["line"] is not None else "-",
             esc(o["component"]), o["standardised_residual"]] for o in flagged]
    return [intro, table("Flagged rows", ["configuration", "row", "CSV line", "component",
                                          "standardised residual"], rows,
                         "Standardised residual: predicted minus measured, in noise std.")]


def robust_noise_scale(model: Hypothesis, measured: np.ndarray, scale: float,
                       declared_m: float | None, loss: str, options: dict,
                       start_si: float = 1e5, settle: tuple[float, int] | None = None
                       ) -> float:
    """The noise std (m) a robust loss is scaled by: the declared one, else that of
    :func:`robust_rounds` from a least-squares fit (a few gross outliers move it little).

    Parameters
    ----------
    model, measured, scale
        The model, its observations (m) and the residual scale (m) of the fits.
    declared_m
        The declared noise std (m), or ``None``.
    loss
        The robust loss.
    options
        Further keyword arguments of :func:`stiffness.calibration.fitting.fit_model`.
    start_si
        Every stiffness at the start (N.m/rad or N/m).
    settle
        :func:`robust_rounds`' further rounds until the scale settles, ``(tolerance, most)``;
        ``None``: :data:`ROBUST_ROUNDS`.

    Raises
    ------
    StiffnessError
        If the residuals are all zero (nothing to scale a robust loss by).
    """
    if declared_m is not None:
        return declared_m
    x0 = np.full(len(model.compliant), math.log(start_si))
    _, sigma = robust_rounds(
        fit_model(model, measured, scale, x0, anchor=x0, **options),
        lambda fit, s: fit_model(model, measured, scale, fit.x, anchor=x0, loss=loss,
                                 f_scale=s / scale, **options),
        lambda fit: fit.predicted - measured, lambda fit: len(model.compliant), loss,
        settle=settle)
    if sigma is None:
        raise StiffnessError("the residuals are zero: a robust loss has no noise to scale by; "
                             "declare [measurement] noise_std or use --loss linear")
    return sigma
