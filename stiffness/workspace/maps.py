"""The maps of one chunk of a workspace scan: computed, stored, read back, summarised.

* :func:`compute_maps`: per configuration and load case, with :mod:`stiffness.batch.kernels`,
  what the spec's fields (:data:`stiffness.workspace.spec.STORED_FIELDS`) and the summary need:
  the definiteness classes of K_C and of K_theta - K_C, the critical load factor and the sign
  of det K_C (one eigen-decomposition per matrix,
  :func:`stiffness.batch.linalg.load_definiteness`), the enhanced K_X (A&S eq. 10) and its
  principal values, the conventional K_X (eq. 8), the target position. One force (and, if the
  unit-force diagonal is asked, an open chain of one-coordinate joints, where it comes from
  the Jacobian): the generalized-gravity kinematics (two Pinocchio calls per configuration);
  otherwise the kinematic-Hessian basis (any number of loads).
* :func:`stored_arrays`: the arrays written to the chunk files (the chosen fields, symmetric
  K_X as its upper triangle, floats in the spec's dtype);
* :func:`derive`: the maps read back (index, coordinates, full K_X and every derived field);
* :class:`MapAccumulator`: the streaming summary and figure data (memory independent of the
  scan's size).

SI units: rad, m, N, N.m/rad, N/m.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stiffness.batch import kernels as batch
from stiffness.robot.robot import Robot
from stiffness.workspace.spec import COUNT_LABELS, UNDEFINED, ScanSpec

#: Inverse condition number ``sigma_min / sigma_max`` of the target's translational Jacobian
#: below which a configuration is near-singular: its principal stiffnesses (which grow without
#: bound at the singularity) are left out of the summary's ranges, and counted.
SINGULARITY_MARGIN = 0.01
#: What the summary's principal stiffness ranges cover (summary.json ``principal_ranges``).
PRINCIPAL_RANGES = (
    "min/max_principal_stiffness_N_per_m over the valid configurations that are neither "
    "near-singular (near_singular: sigma_min / sigma_max of the target's translational Jacobian "
    "below singularity_margin, where the largest principal stiffness grows without bound) nor "
    "unstable under the load case (unstable: K_theta - K_C not positive definite); for 6-D "
    "loads, of the translational block of K_X (N/m), and min/max_rotational_stiffness_Nm_per_rad "
    "of its rotational block (N.m/rad)")
#: Fields computed together by one eigen-decomposition of the scaled K_C.
DEFINITENESS_FIELDS = ("k_c_class", "tangent_class", "critical_factor", "k_c_det_positive")
#: Per-load-case float fields that are NaN on invalid configurations.
_NAN_WHEN_INVALID = ("position", "critical_factor", "k_c_diagonal", "k_x", "k_x_eigenvalues",
                     "k_x_conventional", "k_x_conventional_eigenvalues", "singularity_ratio")


def needs(spec: ScanSpec) -> dict[str, bool]:
    """What a chunk computes for the spec's fields: definiteness, enhanced and conventional
    K_X, the unit-force basis (k_c_diagonal), the position."""
    fields = set(spec.fields)
    return {"definiteness": bool(fields & set(DEFINITENESS_FIELDS)),
            "k_x": "k_x" in fields, "conventional": "k_x_conventional" in fields,
            "diagonal": "k_c_diagonal" in fields, "position": "position" in fields}


def compute_maps(robot: Robot, spec: ScanSpec, ids: np.ndarray, coords: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """The maps of configurations ``coords`` (rad, m) with global indices ``ids``, float64.

    Returns
    -------
    dict
        ``index`` (c,), ``coordinates`` (c, n_coordinates), ``valid`` (c,), and as needed
        (:func:`needs`): ``position`` (c, 3) m; ``k_c_class``, ``tangent_class`` (c, L) int8
        codes into DEFINITENESS_CLASSES (-1 invalid), ``critical_factor`` (c, L),
        ``k_c_det_positive`` (c, L); ``k_c_diagonal`` (c, 3, n) N.m/rad per N; ``k_x``
        (c, L, r, r) N/m, ``k_x_eigenvalues`` (c, L, r), ``k_x_class`` (c, L), ``regular``
        (c, L), ``singularity_ratio`` (c,) (``sigma_min / sigma_max`` of the translational
        Jacobian; not stored); ``k_x_conventional`` (c, r, r) and
        ``k_x_conventional_eigenvalues`` (c, r).
    """
    want = needs(spec)
    loads = np.asarray(spec.loads, dtype=float)
    k_theta = batch.as_joint_stiffness(spec.k_theta, robot.n_compliant)
    rows = spec.rows
    closed = batch.close_loops(robot, coords)
    q = np.where(closed.closed[:, None], closed.q, batch.tree_configurations(robot, coords))
    moments = spec.moments
    out: dict[str, np.ndarray] = {"index": ids, "coordinates": coords}
    single_force = loads.shape[0] == 1 and not moments and (
        not want["diagonal"] or (robot.loop.is_open_chain and batch.one_coordinate_joints(robot)
                                 and not robot.springs_on_controller))
    if single_force:
        jac, k_c, kin_valid, position = batch.single_force_block(
            robot, q, loads[0, :3], pose=want["position"])
        k_c = k_c[:, None]
        if want["diagonal"]:
            out["k_c_diagonal"] = batch.unit_force_diagonal(robot, jac)
    else:
        kin = batch.batch_kinematics(robot, q, moments=moments, pose=want["position"])
        jac, kin_valid, position = kin.jacobian, kin.valid, kin.position
        k_c = batch.complementary_stiffness(kin, loads)
        if want["diagonal"]:
            out["k_c_diagonal"] = np.diagonal(kin.k_c_basis[:, :3], axis1=-2,
                                              axis2=-1).copy()
    valid = closed.closed & kin_valid
    out["valid"] = valid
    if position is not None:  # asked for (want["position"])
        out["position"] = position
    if want["definiteness"]:
        d = batch.load_definiteness(k_theta, k_c, rtol=spec.rtol)
        out.update(k_c_class=d.k_c_class, tangent_class=d.tangent_class,
                   critical_factor=d.critical_factor, k_c_det_positive=d.determinant_positive)
    if want["k_x"]:
        tangent = k_theta - k_c
        if moments:
            _, k_x, _, ok = batch.compliance_stack(tangent, jac[:, None, :rows], True)
        else:
            _, k_x, ok = batch.symmetric_stack(k_theta, k_c, jac[:, :rows])
        eig = batch.symmetric_eigenvalues(k_x)
        out.update(k_x=k_x, k_x_eigenvalues=eig, regular=ok & valid[:, None],
                   k_x_class=batch.definiteness_codes(eigenvalues=eig, rtol=spec.rtol),
                   singularity_ratio=singularity_ratio(jac[:, :3]))
    if want["conventional"]:
        _, k_conv, ok_conv = batch.symmetric_stack(k_theta, None, jac[:, :rows])
        out["k_x_conventional"] = k_conv[:, 0]
        out["regular_conventional"] = ok_conv[:, 0] & valid
        out["k_x_conventional_eigenvalues"] = batch.symmetric_eigenvalues(k_conv[:, 0])
    invalid = ~valid
    if invalid.any():
        for key in _NAN_WHEN_INVALID:
            if key in out:
                out[key] = out[key].astype(float, copy=True)
                out[key][invalid] = np.nan
        for key in ("k_c_class", "tangent_class", "k_x_class"):
            if key in out:
                out[key][invalid] = batch.INVALID_CLASS
        if "k_c_det_positive" in out:
            out["k_c_det_positive"][invalid] = False
    return out


def singularity_ratio(jac: np.ndarray) -> np.ndarray:
    """``sigma_min / sigma_max`` of each (3, n) translational Jacobian (0 at a singularity or
    with fewer than three joints, 1 when the target moves alike in every direction).

    The singular values are the square roots of the eigenvalues of ``J J^T`` (3 x 3, closed
    form: a quarter of the SVD's cost); ratios below about 1e-8 read as that floor or 0.
    """
    finite = np.where(np.isfinite(jac), jac, 0.0)
    gram = batch.symmetric_eigenvalues(np.einsum("cik,cjk->cij", finite, finite))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(gram[..., -1] > 0,
                         np.sqrt(np.clip(gram[..., 0], 0.0, None) / gram[..., -1]), 0.0)
    if jac.shape[-1] < jac.shape[-2]:
        ratio = np.zeros(jac.shape[0])
    return np.where(np.all(np.isfinite(jac), axis=(-2, -1)), ratio, np.nan)


def block_eigenvalues(k_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal values of the translational (N/m) and rotational (N.m/rad) diagonal blocks
    of 6x6 stiffnesses ``k_x`` (..., 6, 6), ascending (NaN where ``k_x`` is not finite)."""
    return (batch.symmetric_eigenvalues(k_x[..., :3, :3]),
            batch.symmetric_eigenvalues(k_x[..., 3:, 3:]))


# ---------------------------------------------------------------------------------- storage


def _packed(spec: ScanSpec, name: str) -> bool:
    """Whether a K_X field is stored as its upper triangle (symmetric: no moment loads)."""
    return name in ("k_x", "k_x_conventional") and not spec.moments


def stored_arrays(spec: ScanSpec, maps: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays of a chunk file: the spec's fields, K_X of force loads as the upper triangle
    (``<name>_upper``, rows of ``np.triu_indices(r)``), floats as ``spec.dtype``."""
    dtype = np.dtype(spec.dtype)
    upper = np.triu_indices(spec.rows)
    out = {}
    for name in spec.fields:
        value = maps[name]
        if _packed(spec, name):
            value, name = value[..., upper[0], upper[1]], f"{name}_upper"
        if value.dtype.kind == "f":
            with np.errstate(over="ignore"):  # a critical factor beyond float32 is inf
                value = value.astype(dtype, copy=False)
        out[name] = np.ascontiguousarray(value)
    return out


def derive(spec: ScanSpec, index: int, stored: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The maps of chunk ``index`` read back from its stored arrays (float64).

    Adds ``index``, ``coordinates`` (from the spec: exact, whatever the storage dtype), the
    full K_X and the
    derived fields: ``k_x_eigenvalues``, ``k_x_class``, ``regular``,
    ``k_x_conventional_eigenvalues``.
    """
    ids, coords = spec.chunk_coordinates(index)
    out = {"index": ids, "coordinates": coords}
    r = spec.rows
    upper = np.triu_indices(r)
    for name, value in stored.items():
        if name == "coordinates":  # the spec's exact values (the stored copy may be float32)
            continue
        if value.dtype.kind == "f":
            value = value.astype(float)
        if name.endswith("_upper"):
            name = name[: -len("_upper")]
            full = np.empty((*value.shape[:-1], r, r))
            full[..., upper[0], upper[1]] = value
            full[..., upper[1], upper[0]] = value
            value = full
        out[name] = value
    if "k_x" in out:
        eig = batch.symmetric_eigenvalues(out["k_x"])
        valid = out["valid"] if "valid" in out else np.ones(ids.shape[0], dtype=bool)
        out["k_x_eigenvalues"] = eig
        out["k_x_class"] = batch.definiteness_codes(eigenvalues=eig, rtol=spec.rtol)
        out["regular"] = np.all(np.isfinite(out["k_x"]), axis=(-2, -1)) & valid[:, None]
    if "k_x_conventional" in out:
        valid = out["valid"] if "valid" in out else np.ones(ids.shape[0], dtype=bool)
        out["k_x_conventional_eigenvalues"] = batch.symmetric_eigenvalues(
            out["k_x_conventional"])
        out["regular_conventional"] = np.all(np.isfinite(out["k_x_conventional"]),
                                             axis=(-2, -1)) & valid
    return out


# ---------------------------------------------------------------------------------- aggregate


class MapAccumulator:
    """Streaming summary and figure data of a scan (memory independent of its size).

    Per load case: class counts of K_C, K_theta - K_C and K_X, det K_C > 0 counts, the smallest
    critical load factor and the extreme principal stiffnesses; per bin of the map axes: the
    smallest principal stiffness of K_X (over the other coordinates) and the class counts of K_C.
    Quantities a scan's fields do not compute (:func:`needs`) stay empty and are left out of
    the summary. ``bytes`` counts the bytes of the chunk files written.
    """

    def __init__(self, spec: ScanSpec) -> None:
        self.spec = spec
        self.needs = needs(spec)
        n_loads = len(spec.loads)
        self.edges = [spec.bin_edges(spec.axes[i]) for i in spec.map_axes]
        shape = tuple(len(e) - 1 for e in self.edges)
        k = len(COUNT_LABELS)
        self.parts = {
            "n": np.zeros(1, dtype=np.int64),
            "n_valid": np.zeros(1, dtype=np.int64),
            "bytes": np.zeros(1, dtype=np.int64),
            "k_c_counts": np.zeros((n_loads, k), dtype=np.int64),
            "tangent_counts": np.zeros((n_loads, k), dtype=np.int64),
            "k_x_counts": np.zeros((n_loads, k), dtype=np.int64),
            "det_positive": np.zeros(n_loads, dtype=np.int64),
            "critical_min": np.full(n_loads, np.inf),
            "critical_argmin": np.full(n_loads, -1, dtype=np.int64),
            "k_x_min": np.full(n_loads, np.inf),
            "k_x_max": np.full(n_loads, -np.inf),
            "k_x_rotational_min": np.full(n_loads, np.inf),
            "k_x_rotational_max": np.full(n_loads, -np.inf),
            "near_singular": np.zeros(1, dtype=np.int64),
            "unstable": np.zeros(n_loads, dtype=np.int64),
            "k_x_conventional_min": np.full(1, np.inf),
            "k_x_conventional_max": np.full(1, -np.inf),
            "map_min_stiffness": np.full((*shape, n_loads), np.inf),
            "map_conventional_min": np.full(shape, np.inf),
            "map_min_ratio": np.full((*shape, n_loads), np.inf),
            "map_k_c_counts": np.zeros((*shape, n_loads, k), dtype=np.int64),
        }

    def chunk_parts(self, maps: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A chunk's contribution (same keys as the totals)."""
        spec = self.spec
        n_loads = len(spec.loads)
        k = len(COUNT_LABELS)
        parts = {key: value.copy() for key, value in self.parts.items()}
        valid = maps["valid"]
        parts["n"][0] = valid.shape[0]
        parts["n_valid"][0] = int(valid.sum())
        for name in ("k_c", "tangent", "k_x"):
            if f"{name}_class" not in maps:
                continue
            codes = np.where(maps[f"{name}_class"] < 0, k - 1, maps[f"{name}_class"])
            for j in range(n_loads):
                parts[f"{name}_counts"][j] = np.bincount(codes[:, j], minlength=k)
        if "k_c_det_positive" in maps:
            parts["det_positive"] = maps["k_c_det_positive"].sum(axis=0)
        if "critical_factor" in maps and valid.shape[0]:
            crit = np.where(np.isnan(maps["critical_factor"]), np.inf, maps["critical_factor"])
            arg = np.argmin(crit, axis=0)
            parts["critical_min"] = crit[arg, np.arange(n_loads)]
            parts["critical_argmin"] = np.where(np.isfinite(parts["critical_min"]),
                                                maps["index"][arg], -1)
        low = conv = None
        with np.errstate(invalid="ignore"):
            if "k_x_eigenvalues" in maps:
                low = maps["k_x_eigenvalues"][..., 0]
                self._principal_ranges(parts, maps)
            if "k_x_conventional_eigenvalues" in maps:
                conv = maps["k_x_conventional_eigenvalues"]
                parts["k_x_conventional_min"][0] = _nanreduce(np.nanmin, conv[:, 0], np.inf)
                parts["k_x_conventional_max"][0] = _nanreduce(np.nanmax, conv[:, -1], -np.inf)
        if self.edges:
            self._bin(parts, maps, low, conv)
        return parts

    def _principal_ranges(self, parts: dict[str, np.ndarray], maps: dict[str, np.ndarray]
                          ) -> None:
        """The chunk's extreme principal stiffnesses over the configurations the summary keeps:
        neither near-singular (:data:`SINGULARITY_MARGIN`) nor unstable (K_theta - K_C not
        positive definite; K_X not positive definite when the tangent is not computed), each
        counted. A 6x6 K_X gives its translational (N/m) and rotational (N.m/rad) blocks'."""
        valid = maps["valid"]
        ratio = maps.get("singularity_ratio")
        near = np.zeros(valid.shape[0], dtype=bool) if ratio is None else \
            np.nan_to_num(ratio, nan=np.inf) < SINGULARITY_MARGIN
        stable_class = maps["tangent_class"] if "tangent_class" in maps else maps["k_x_class"]
        unstable = (stable_class != batch.CLASS_CODES["PD"]) & valid[:, None]
        parts["near_singular"][0] = int((near & valid).sum())
        parts["unstable"] = unstable.sum(axis=0)
        keep = ~near[:, None] & ~unstable
        if self.spec.rows == 6:
            translational, rotational = block_eigenvalues(maps["k_x"])
            rot = np.where(keep[..., None], rotational, np.nan)
            parts["k_x_rotational_min"] = np.fmin(parts["k_x_rotational_min"], _nanreduce(
                np.nanmin, rot[..., 0], np.inf))
            parts["k_x_rotational_max"] = np.fmax(parts["k_x_rotational_max"], _nanreduce(
                np.nanmax, rot[..., -1], -np.inf))
        else:
            translational = maps["k_x_eigenvalues"]
        kept = np.where(keep[..., None], translational, np.nan)
        parts["k_x_min"] = np.fmin(parts["k_x_min"], _nanreduce(np.nanmin, kept[..., 0], np.inf))
        parts["k_x_max"] = np.fmax(parts["k_x_max"], _nanreduce(np.nanmax, kept[..., -1],
                                                                -np.inf))

    def _bin(self, parts: dict[str, np.ndarray], maps: dict[str, np.ndarray],
             low: np.ndarray | None, conv: np.ndarray | None) -> None:
        """Fold a chunk into the per-bin maps."""
        spec = self.spec
        n_loads, k = len(spec.loads), len(COUNT_LABELS)
        cells = [np.clip(np.digitize(maps["coordinates"][:, spec.axes[i]["index"]], e) - 1,
                         0, len(e) - 2) for i, e in zip(spec.map_axes, self.edges, strict=True)]
        flat = np.ravel_multi_index(cells, parts["map_conventional_min"].shape)
        size = parts["map_conventional_min"].size
        if low is not None:
            lowest = parts["map_min_stiffness"].reshape(size, n_loads)
            np.fmin.at(lowest, flat, np.where(np.isnan(low), np.inf, low))
        if conv is not None:
            conv_low = parts["map_conventional_min"].reshape(size)
            np.fmin.at(conv_low, flat, np.where(np.isnan(conv[:, 0]), np.inf, conv[:, 0]))
        if low is not None and conv is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = low / conv[:, :1]
            ratios = parts["map_min_ratio"].reshape(size, n_loads)
            np.fmin.at(ratios, flat, np.where(np.isfinite(ratio), ratio, np.inf))
        if "k_c_class" in maps:
            codes = np.where(maps["k_c_class"] < 0, k - 1, maps["k_c_class"])
            cell = (flat[:, None] * n_loads + np.arange(n_loads)[None, :]) * k + codes
            parts["map_k_c_counts"] += np.bincount(
                cell.reshape(-1), minlength=size * n_loads * k).reshape(
                parts["map_k_c_counts"].shape)

    def add(self, parts: dict[str, np.ndarray]) -> None:
        """Merge a chunk's contribution."""
        p = self.parts
        for key in ("n", "n_valid", "bytes", "k_c_counts", "tangent_counts", "k_x_counts",
                    "det_positive", "map_k_c_counts", "near_singular", "unstable"):
            p[key] = p[key] + parts.get(key, 0)  # (aggregates of older scans lack some)
        better = parts["critical_min"] < p["critical_min"]
        p["critical_min"] = np.where(better, parts["critical_min"], p["critical_min"])
        p["critical_argmin"] = np.where(better, parts["critical_argmin"], p["critical_argmin"])
        for key in ("k_x_min", "k_x_conventional_min", "map_min_stiffness",
                    "map_conventional_min", "map_min_ratio", "k_x_rotational_min"):
            p[key] = np.fmin(p[key], parts.get(key, np.inf))
        for key in ("k_x_max", "k_x_conventional_max", "k_x_rotational_max"):
            p[key] = np.fmax(p[key], parts.get(key, -np.inf))

    def summary(self) -> dict:
        """JSON-ready summary of the scan so far."""
        spec, p, want = self.spec, self.parts, self.needs
        cases = {}
        for j, name in enumerate(spec.load_names):
            case: dict = {"load": spec.loads[j]}
            if want["definiteness"]:
                crit = float(p["critical_min"][j])
                magnitude = float(np.linalg.norm(spec.loads[j][:3]))
                case.update({
                    "k_c": _counts(p["k_c_counts"][j]),
                    "k_theta_minus_k_c": _counts(p["tangent_counts"][j]),
                    "k_c_determinant_positive": int(p["det_positive"][j]),
                    "min_critical_load_factor": _finite_or_none(crit),
                    "min_critical_force_N": _finite_or_none(crit * magnitude)
                    if magnitude > 0 else None,
                    "min_critical_configuration": int(p["critical_argmin"][j]),
                })
            if want["k_x"]:
                case.update({
                    "k_x_undefined": int(p["k_x_counts"][j][-1])
                    - int(p["n"][0] - p["n_valid"][0]),
                    "k_x": _counts(p["k_x_counts"][j]),
                    "unstable": int(p["unstable"][j]),
                    "min_principal_stiffness_N_per_m": _finite_or_none(float(p["k_x_min"][j])),
                    "max_principal_stiffness_N_per_m": _finite_or_none(float(p["k_x_max"][j])),
                })
                if spec.rows == 6:
                    case.update({
                        "min_rotational_stiffness_Nm_per_rad": _finite_or_none(
                            float(p["k_x_rotational_min"][j])),
                        "max_rotational_stiffness_Nm_per_rad": _finite_or_none(
                            float(p["k_x_rotational_max"][j]))})
            cases[name] = case
        out = {
            "robot": spec.robot["source"],
            "preset": spec.preset,
            "configurations": int(p["n"][0]),
            "valid_configurations": int(p["n_valid"][0]),
            "load_cases": cases,
        }
        if want["k_x"]:
            out["near_singular"] = int(p["near_singular"][0])
            out["singularity_margin"] = SINGULARITY_MARGIN
            out["principal_ranges"] = PRINCIPAL_RANGES
        out["undefined"] = UNDEFINED
        if want["conventional"]:
            out["conventional_min_principal_stiffness_N_per_m"] = _finite_or_none(
                float(p["k_x_conventional_min"][0]))
            out["conventional_max_principal_stiffness_N_per_m"] = _finite_or_none(
                float(p["k_x_conventional_max"][0]))
        return out


def _nanreduce(func: Callable[..., np.ndarray], values: np.ndarray, empty: float
               ) -> np.ndarray | float:
    """``func(values, axis=0)`` for a NaN-ignoring ``func``; ``empty`` where no value is."""
    if values.shape[0] == 0 or np.all(np.isnan(values)):
        return np.full(values.shape[1:], empty) if values.ndim > 1 else empty
    out = func(values, axis=0)
    return np.where(np.isnan(out), empty, out)


def _counts(row: np.ndarray) -> dict[str, int]:
    """Class counts of one load case, by :data:`COUNT_LABELS`."""
    return {label: int(v) for label, v in zip(COUNT_LABELS, row, strict=True)}


def _finite_or_none(value: float) -> float | None:
    """``value``, or None when it is not finite (JSON has no inf)."""
    return value if np.isfinite(value) else None
