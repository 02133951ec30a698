"""Workspace scan engine: stiffness and definiteness maps over many configurations, chunked.

A scan (:class:`stiffness.workspace.spec.ScanSpec`) is cut into chunks of ``spec.chunk_size``
configurations; a chunk is a pure function of (spec, index) (:func:`scan_chunk`, computed by
:func:`stiffness.workspace.maps.compute_maps`), so any process can compute it. :func:`run_scan`
runs the missing chunks through :func:`stiffness.workspace.distributed.run_chunks` (in this process,
on a Dask LocalCluster or on a remote cluster), in tasks of one or more consecutive chunks,
writes each chunk to the output folder as soon as it is done (NPZ and/or Parquet, by the
process that computed it when it shares the folder), so memory is bounded by the chunk size and
a killed run loses only unfinished chunks, and folds each chunk's small aggregate into a
streaming :class:`~stiffness.workspace.maps.MapAccumulator` for the summary and the figures
(:mod:`stiffness.workspace.plots`). Running it again on the same folder resumes the scan.

Files in the output folder:

* ``manifest.json``: the scan's specification (robot, coordinates, loads, K_theta, fields,
  dtype, units);
* ``chunks/chunk-NNNNN.npz`` ("npz": the stored fields, see
  :data:`stiffness.workspace.spec.STORED_FIELDS`) and/or ``maps.parquet/part-NNNNN.parquet``
  ("parquet", one row per configuration and load case);
* ``chunks/aggregate-NNNNN.npz``: the chunk's contribution to the summary (marks it done);
* ``summary.json`` (class counts per load case, extremes, bytes per configuration) and the
  figures ``definiteness_counts.png``, ``definiteness_map.png``, ``stiffness_map.png``.

:func:`load_scan` reads the NPZ chunks back with the derived arrays rebuilt
(:func:`stiffness.workspace.maps.derive`). SI units: rad, m, N, N.m/rad, N/m.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from stiffness.errors import MissingFileError, StiffnessError
from stiffness.files import atomic_write, atomic_write_with, staged_folder, written_source
from stiffness.mechanics.formulation import DEFINITENESS_CLASSES
from stiffness.workspace.distributed import run_chunks, warm_worker, worker_robot
from stiffness.workspace.maps import MapAccumulator, compute_maps, derive, stored_arrays
from stiffness.workspace.spec import LAYOUT_VERSION, UNDEFINED, ScanSpec

# ---------------------------------------------------------------------------------- chunk


def scan_chunk(spec_dict: dict, index: int) -> dict[str, np.ndarray]:
    """Compute chunk ``index`` of a scan (runs on a worker; a pure function of its inputs).

    Returns the float64 maps of :func:`stiffness.workspace.maps.compute_maps`.
    """
    spec = ScanSpec.from_dict(spec_dict)
    robot = worker_robot(spec.robot)
    return compute_maps(robot, spec, *spec.chunk_coordinates(index))


# ---------------------------------------------------------------------------------- files


def chunk_path(out: Path, index: int) -> Path:
    """NPZ file of chunk ``index``."""
    return out / "chunks" / f"chunk-{index:05d}.npz"


def parquet_path(out: Path, index: int) -> Path:
    """Parquet part file of chunk ``index``."""
    return out / "maps.parquet" / f"part-{index:05d}.parquet"


def aggregate_path(out: Path, index: int) -> Path:
    """Aggregate file of chunk ``index`` (written last: the chunk is done)."""
    return out / "chunks" / f"aggregate-{index:05d}.npz"


def write_npz(path: Path, arrays: dict[str, np.ndarray], compressed: bool = False) -> int:
    """Write arrays to an NPZ file atomically (deflate when ``compressed``); returns its size
    in bytes."""
    save: Callable[..., None] = np.savez_compressed if compressed else np.savez
    atomic_write_with(path, lambda f: save(f, **arrays))
    return path.stat().st_size


def write_parquet(path: Path, spec: ScanSpec, maps: dict[str, np.ndarray]) -> int:
    """One row per configuration and load case (tidy table, for tools that cannot rebuild the
    derived arrays), written atomically with the spec's compression; returns its size (bytes).

    Columns, each with the stored field it comes from: ``configuration``, ``load_case`` and
    ``q_<joint>`` always; ``x_m``, ``y_m``, ``z_m`` (position); ``valid``; ``k_c_class``,
    ``tangent_class`` (class names), ``critical_factor``, ``k_c_det_positive``;
    ``k_c_diag_<f><j>`` (k_c_diagonal: unit force f = x, y, z, joint j); ``k_x_class``,
    ``regular``, ``k_x_eig<k>_N_per_m`` and ``k_x_<a><b>`` (k_x); ``regular_conventional``,
    ``k_x_conventional_eig<k>_N_per_m`` and ``k_x_conventional_<a><b>`` (k_x_conventional).
    """
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise StiffnessError("--format parquet needs pyarrow: pip install pyarrow") from exc
    c, n_loads = maps["index"].shape[0], len(spec.loads)
    rows = spec.rows
    dtype = np.dtype(spec.dtype)
    names = np.array([*DEFINITENESS_CLASSES, ""])
    fields = set(spec.fields)

    def column(values: np.ndarray, per_config: bool) -> np.ndarray:
        values = np.repeat(values, n_loads) if per_config else values.reshape(-1)
        with np.errstate(over="ignore"):  # a critical factor beyond float32 is inf
            return values.astype(dtype) if values.dtype.kind == "f" else values

    table = {
        "configuration": np.repeat(maps["index"], n_loads),
        "load_case": np.tile(np.array(spec.load_names), c),
    }
    for k, joint in enumerate(spec.coordinate_joints):
        table[f"q_{joint}"] = column(maps["coordinates"][:, k], True)
    if "position" in fields:
        for k, axis in enumerate("xyz"):
            table[f"{axis}_m"] = column(maps["position"][:, k], True)
    if "valid" in fields:
        table["valid"] = column(maps["valid"], True)
    for name in ("k_c_class", "tangent_class", "critical_factor", "k_c_det_positive"):
        if name in fields:
            values = maps[name]
            table[name] = names[values.reshape(-1)] if name.endswith("_class") else column(
                values, False)
    if "k_c_diagonal" in fields:
        for f, axis in enumerate("xyz"):
            for j in range(maps["k_c_diagonal"].shape[2]):
                table[f"k_c_diag_{axis}{j}"] = column(maps["k_c_diagonal"][:, f, j], True)
    if "k_x" in fields:
        table["k_x_class"] = names[maps["k_x_class"].reshape(-1)]
        table["regular"] = maps["regular"].reshape(-1)
        for k in range(rows):
            table[f"k_x_eig{k}_N_per_m"] = column(maps["k_x_eigenvalues"][..., k], False)
        for a in range(rows):
            for b in range(rows):
                table[f"k_x_{a}{b}"] = column(maps["k_x"][:, :, a, b], False)
    if "k_x_conventional" in fields:
        table["regular_conventional"] = column(maps["regular_conventional"], True)
        for k in range(rows):
            table[f"k_x_conventional_eig{k}_N_per_m"] = column(
                maps["k_x_conventional_eigenvalues"][:, k], True)
        for a in range(rows):
            for b in range(rows):
                table[f"k_x_conventional_{a}{b}"] = column(maps["k_x_conventional"][:, a, b],
                                                           True)
    arrow = pa.table(table)
    codec = spec.compression or "snappy"
    atomic_write_with(path, lambda f: pq.write_table(arrow, f, compression=codec))
    return path.stat().st_size


def write_chunk(out: Path, spec: ScanSpec, index: int, maps: dict[str, np.ndarray],
                formats: tuple[str, ...], parts: dict[str, np.ndarray] | None = None
                ) -> dict[str, np.ndarray]:
    """Write a chunk's map files, then its aggregate (which marks it done); returns the
    aggregate (:meth:`MapAccumulator.chunk_parts`, computed here unless given) with the bytes
    written."""
    if parts is None:
        parts = MapAccumulator(spec).chunk_parts(maps)
    stored = stored_arrays(spec, maps) if "npz" in formats else None
    return _write_files(out, spec, index, stored,
                        maps if "parquet" in formats else None, parts)


def _write_files(out: Path, spec: ScanSpec, index: int, stored: dict[str, np.ndarray] | None,
                 maps: dict[str, np.ndarray] | None, parts: dict[str, np.ndarray]
                 ) -> dict[str, np.ndarray]:
    """Write chunk ``index``'s NPZ (its ``stored`` arrays, if given) and Parquet part (of its
    ``maps``, if given), then its aggregate ``parts`` with the bytes written (which marks the
    chunk done); returns ``parts``."""
    written = 0
    if stored is not None:
        written += write_npz(chunk_path(out, index), stored,
                             compressed=spec.compression not in (None, "none"))
    if maps is not None:
        written += write_parquet(parquet_path(out, index), spec, maps)
    parts["bytes"] = np.array([written], dtype=np.int64)
    write_npz(aggregate_path(out, index), parts)
    return parts


class ChunkWriter:
    """Writes computed chunks (:func:`write_chunk`) on one background thread, so that a
    chunk's files are written (and synced) while the next chunk computes; at most
    :attr:`DEPTH` chunks wait, so memory stays bounded by the chunk size.

    ``on_written(index, aggregate)`` is called in the submitting thread, in submission order,
    once a chunk's files are on disk. Leaving the ``with`` block finishes every submitted
    chunk (also when the computation raised, so that finished chunks are kept for a resume)
    and re-raises a write error.
    """

    DEPTH = 2

    def __init__(self, out: Path, spec: ScanSpec, formats: tuple[str, ...],
                 on_written: Callable[[int, dict[str, np.ndarray]], None]) -> None:
        self._out, self._spec, self._formats = out, spec, formats
        self._on_written = on_written
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="scan-writer")
        self._pending: deque = deque()

    def submit(self, index: int, maps: dict[str, np.ndarray]) -> None:
        """Queue chunk ``index`` (its float64 maps) for writing."""
        while len(self._pending) >= self.DEPTH:
            self._finish_oldest()
        self._pending.append((index, self._executor.submit(
            write_chunk, self._out, self._spec, index, maps, self._formats)))

    def _finish_oldest(self) -> None:
        index, future = self._pending.popleft()
        self._on_written(index, future.result())

    def __enter__(self) -> ChunkWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        try:
            while self._pending:
                self._finish_oldest()
        finally:
            for _, future in self._pending:
                future.cancel()
            self._executor.shutdown(wait=True)


def scan_chunks_to_files(spec_dict: dict, out: str, formats: tuple[str, ...],
                         indices: tuple[int, ...]) -> dict[int, dict[str, np.ndarray]]:
    """Compute consecutive chunks and write their files where they run (a worker sharing the
    output folder's filesystem), each chunk's while the next computes (:class:`ChunkWriter`);
    only the small aggregates travel back, ``{index: aggregate}``."""
    done: dict[int, dict[str, np.ndarray]] = {}
    with ChunkWriter(Path(out), ScanSpec.from_dict(spec_dict), tuple(formats),
                     done.__setitem__) as writer:
        for index in indices:
            writer.submit(index, scan_chunk(spec_dict, index))
    return done


def scan_chunk_stored(spec_dict: dict, index: int
                      ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Compute chunk ``index`` for a client that writes it: its aggregate and its stored
    arrays (the fields in the spec's dtype, packed; not the float64 maps)."""
    spec = ScanSpec.from_dict(spec_dict)
    maps = scan_chunk(spec_dict, index)
    return MapAccumulator(spec).chunk_parts(maps), stored_arrays(spec, maps)


def load_scan(out: str | os.PathLike) -> dict[str, np.ndarray]:
    """All NPZ chunks of a scan, derived arrays rebuilt, concatenated in configuration order
    (memory grows with the scan)."""
    out = Path(out)
    files = sorted((out / "chunks").glob("chunk-*.npz"))
    if not files:
        raise MissingFileError(f"{out} holds no NPZ chunk (chunks/chunk-*.npz); was it written "
                               "with --format parquet?", path=out)
    spec = _manifest_spec(out)
    parts = [derive(spec, int(f.stem.split("-")[1]), dict(np.load(f))) for f in files]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def _manifest_spec(out: Path) -> ScanSpec:
    """The spec of the scan in ``out`` (its manifest.json)."""
    manifest = out / "manifest.json"
    if not manifest.is_file():
        raise MissingFileError(f"{out} is not a scan folder (no manifest.json)", path=out)
    data = json.loads(manifest.read_text())
    if data.get("layout") != LAYOUT_VERSION:
        raise StiffnessError(
            f"{out} was written with chunk layout {data.get('layout')}; this version reads "
            f"layout {LAYOUT_VERSION}: rerun the scan into a new folder"
        )
    return ScanSpec.from_dict(data["spec"], out)


# ---------------------------------------------------------------------------------- run


#: Largest map of the figures (bins of the map axes times the load cases): a 2000 x 2000 map.
MAX_MAP_CELLS = 4_000_000


def stored_bytes_per_configuration(spec: ScanSpec) -> int:
    """Bytes one configuration adds to a chunk file (the spec's fields, packed and typed as
    stored: :func:`stiffness.workspace.maps.stored_arrays` of one computed configuration)."""
    ids, coords = spec.chunk_coordinates(0)
    maps = compute_maps(worker_robot(spec.robot), spec, ids[:1], coords[:1])
    return sum(a.nbytes for a in stored_arrays(spec, maps).values())


def check_scan_size(spec: ScanSpec, out: Path, formats: tuple[str, ...]) -> None:
    """Refuse, before anything is written, a scan whose figures' maps would not fit in memory
    or whose files would not fit on the disk holding ``out``.

    The projection is a lower bound: the configurations still to write times the bytes each
    adds to an NPZ chunk (:func:`stored_bytes_per_configuration`), per format, less what
    ``out`` already holds (a scan being resumed).

    Raises
    ------
    StiffnessError
        The maps exceed :data:`MAX_MAP_CELLS`, or the projected bytes exceed the free space
        (both named, with the options that shrink the scan).
    """
    if spec.map_cells > MAX_MAP_CELLS:
        raise StiffnessError(
            f"the figures' maps would have {spec.map_cells:.3g} cells (map axes "
            f"{' x '.join(str(spec.axis_lengths[i]) for i in spec.map_axes)}, "
            f"{len(spec.loads)} load case{'s' if len(spec.loads) != 1 else ''}), more than "
            f"{MAX_MAP_CELLS:.0e}; use a coarser STEP on the map axes (or --map-axes on shorter "
            "ones)")
    need = spec.n_configurations * stored_bytes_per_configuration(spec) * len(formats)
    need -= sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) if out.is_dir() else 0
    folder = out
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if need > free:
        raise StiffnessError(
            f"the scan would write at least {need / 1e9:.3g} GB ({spec.n_configurations:.4g} "
            f"configurations) but {folder} has {free / 1e9:.3g} GB free; scan fewer "
            "configurations (--samples, a coarser --axis STEP), store fewer --fields, use "
            "--dtype float32, or give --out on a larger disk")


def _finished_aggregates(out: Path, n_chunks: int) -> list[int]:
    """Indices of the chunks whose aggregate file exists (one listing of ``out/chunks``)."""
    folder = out / "chunks"
    if not folder.is_dir():
        return []
    found = []
    for entry in os.scandir(folder):
        stem, _, index = entry.name.removesuffix(".npz").partition("-")
        if stem == "aggregate" and index.isdigit() and int(index) < n_chunks:
            found.append(int(index))
    return sorted(found)


def run_scan(spec: ScanSpec, out: str | os.PathLike, formats: tuple[str, ...] = ("npz",),
             scheduler: str | None = None, workers: int | None = None,
             client: object | None = None, plots: bool = True,
             progress: Callable[[int, int], None] | None = None,
             write_on_workers: bool | None = None, chunks_per_task: int | None = None) -> dict:
    """Run (or resume) a scan into ``out``; returns the summary.

    Parameters
    ----------
    spec
        What to compute.
    out
        Output folder; if it holds a scan with the same spec, its finished chunks are kept.
        It is built beside ``out`` and published by one rename
        (:func:`stiffness.files.staged_folder`); a scan killed on the way is resumed from the
        folder it was building.
    formats
        "npz" and/or "parquet".
    scheduler, workers, client
        Where the chunks run (see :func:`stiffness.workspace.distributed.run_chunks`). A script that
        starts a LocalCluster (``workers`` > 1) must guard its entry point with
        ``if __name__ == "__main__":`` (worker processes are spawned).
    plots
        Draw the figures.
    progress
        Called with (configurations done, total).
    write_on_workers
        On Dask: each chunk's files are written by the worker that computes it and only its
        aggregate travels back (needs ``out`` on a filesystem the workers share); otherwise
        the chunk's stored arrays travel back and this process writes them. Default: True on
        a LocalCluster, False on a remote scheduler or a given client. In this process (no
        Dask), a :class:`ChunkWriter` thread writes each chunk while the next one computes.
    chunks_per_task
        Consecutive chunks computed by one Dask task; default chosen from the measured
        per-task overhead (:func:`stiffness.workspace.distributed.run_chunks`).

    Returns
    -------
    dict
        JSON-ready summary (:meth:`MapAccumulator.summary`) with ``chunks`` (total, computed,
        resumed, chunk_size), ``dask`` (on a cluster: chunks per task, measured per-task
        overhead and per-chunk time, workers), ``compute_seconds``, ``bytes_written``,
        ``bytes_per_configuration``, ``fields``, ``dtype``, ``units`` and, with figures,
        ``plot_seconds``; also written to ``out/summary.json``.
    """
    out = Path(out)
    check_scan_size(spec, out, formats)
    with staged_folder(out, resume=True) as folder:  # published whole, by one rename
        return _scan_into(spec, folder, out, formats, scheduler, workers, client, plots,
                          progress, write_on_workers, chunks_per_task)


def _scan_into(spec: ScanSpec, out: Path, shown: Path, formats: tuple[str, ...],
               scheduler: str | None, workers: int | None, client: object | None, plots: bool,
               progress: Callable[[int, int], None] | None, write_on_workers: bool | None,
               chunks_per_task: int | None) -> dict:
    """:func:`run_scan` into the folder ``out`` being built (``shown`` in messages)."""
    manifest = {"layout": LAYOUT_VERSION, "spec": spec.to_dict(shown), "formats": list(formats),
                "n_configurations": spec.n_configurations, "n_chunks": spec.n_chunks,
                "units": _UNITS, "classes": list(DEFINITENESS_CLASSES), "undefined": UNDEFINED}
    manifest_file = out / "manifest.json"
    if manifest_file.is_file():
        previous = json.loads(manifest_file.read_text())
        if previous.get("spec") != json.loads(json.dumps(manifest["spec"])):
            raise StiffnessError(
                f"{shown} holds a different scan (its manifest.json differs); give a new --out "
                "folder, or the same options to resume it"
            )
    else:
        atomic_write(manifest_file, json.dumps(manifest, indent=1))
    acc = MapAccumulator(spec)
    done = set()
    for index in _finished_aggregates(out, spec.n_chunks):
        agg = aggregate_path(out, index)
        have = [chunk_path(out, index).is_file() if "npz" in formats else True,
                parquet_path(out, index).is_file() if "parquet" in formats else True]
        if agg.is_file() and all(have):
            acc.add(dict(np.load(agg)))
            done.add(index)
    total = spec.n_configurations
    counter = {"configurations": sum(
        spec.chunk_range(i)[1] - spec.chunk_range(i)[0] for i in done)}
    if progress is not None and done:
        progress(counter["configurations"], total)

    local = client is None and scheduler is None and (workers is None or workers <= 1)
    if write_on_workers is None:
        write_on_workers = scheduler is None and client is None

    def on_written(index: int, parts: dict[str, np.ndarray]) -> None:
        acc.add(parts)
        counter["configurations"] += int(parts["n"][0])
        if progress is not None:
            progress(counter["configurations"], total)

    t0 = time.perf_counter()
    todo = [i for i in range(spec.n_chunks) if i not in done]
    stats: dict = {}
    if local:  # compute here; one thread writes each chunk while the next one computes
        with ChunkWriter(out, spec, tuple(formats), on_written) as writer:
            computed = run_chunks(scan_chunk, (spec.to_dict(),), todo, writer.submit,
                                  warm=(warm_worker, spec.robot))
    else:
        def on_result(index: int, result) -> None:
            if write_on_workers:
                parts = result
            else:
                parts, stored = result
                parts = _write_stored(out, spec, index, stored, formats, parts)
            on_written(index, parts)

        func: Callable[..., object]
        args: tuple[object, ...]
        if write_on_workers:
            func, args = scan_chunks_to_files, (spec.to_dict(), str(out.resolve()),
                                                tuple(formats))
        else:
            func, args = scan_chunk_stored, (spec.to_dict(),)
        computed = run_chunks(func, args, todo, on_result, scheduler=scheduler,
                              workers=workers, client=client, group=chunks_per_task,
                              warm=(warm_worker, spec.robot), stats=stats,
                              grouped=write_on_workers)
    elapsed = time.perf_counter() - t0
    summary = acc.summary()
    written = int(acc.parts["bytes"][0])
    summary["chunks"] = {"total": spec.n_chunks, "computed": computed, "resumed": len(done),
                         "chunk_size": spec.chunk_size}
    if stats:
        summary["dask"] = stats
    summary["compute_seconds"] = elapsed
    summary["bytes_written"] = written
    summary["bytes_per_configuration"] = written / max(1, int(acc.parts["n"][0]))
    summary["fields"] = list(spec.fields)
    summary["dtype"] = spec.dtype
    summary["units"] = _UNITS
    if plots:
        t1 = time.perf_counter()
        from stiffness.workspace.plots import all_figures  # matplotlib only when drawing

        for name, png in all_figures(spec, acc).items():
            atomic_write(out / name, png)
        summary["plot_seconds"] = time.perf_counter() - t1
    atomic_write(out / "summary.json", json.dumps(  # its robot path relative to the folder
        {**summary, "robot": written_source(summary["robot"], shown)}, indent=1))
    return summary


def _write_stored(out: Path, spec: ScanSpec, index: int, stored: dict[str, np.ndarray],
                  formats: tuple[str, ...], parts: dict[str, np.ndarray]
                  ) -> dict[str, np.ndarray]:
    """Write a chunk that came back as stored arrays (see :func:`scan_chunk_stored`)."""
    maps = derive(spec, index, stored) if "parquet" in formats else None
    return _write_files(out, spec, index, stored if "npz" in formats else None, maps, parts)


_UNITS = {
    "coordinates": "rad (m for prismatic joints)", "position": "m", "loads": "N (N.m)",
    "k_theta": "N.m/rad (N/m prismatic)", "k_c_diagonal": "N.m/rad per N of unit force",
    "k_x": "N/m (translational block)", "k_x_eigenvalues": "N/m",
    "critical_factor": "dimensionless multiplier of the load case",
    "k_x_upper": "upper triangle of K_X, rows of numpy.triu_indices(r), N/m",
}
