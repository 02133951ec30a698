"""CSV files as spreadsheets and rigs write them, through every reader of a user's CSV.

What a person reads as the same table is read as the same numbers (hypothesis,
:func:`fuzzing.spreadsheet_mutation`): column names in another case or with spaces around
them (``Q1``, `` fx ``, ``Tip_X``; the rig import's names stay exact, it refuses with the map
that reads them), a comma ending every line, comment lines, blank or empty rows at the end,
Windows line ends, a byte-order mark. Any byte changed, inserted or deleted
(:func:`fuzzing.byte_mutation`) reads or raises a one-line
:class:`~stiffness.errors.StiffnessError`, never another exception.
"""

from __future__ import annotations

import contextlib
import shutil
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fuzzing import (
    LONG,
    assert_reader_contract,
    byte_mutation,
    spreadsheet_mutation,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from pose_campaigns import write_ur5_tip_campaign
from test_rig_import import BASE_ROWS

from stiffness.calibration.campaign import load_campaign
from stiffness.calibration.campaign_toml import RobotSettings
from stiffness.calibration.pose_campaign import load_pose_campaign
from stiffness.calibration.rig_import import ImportSettings, import_campaign
from stiffness.errors import UnknownColumnWarning

#: Few examples each (the suite stays fast); ``HYPOTHESIS_PROFILE=long`` runs more.
EDGES = settings(max_examples=1000 if LONG else 25, deadline=None)
TABLE2 = Path(__file__).resolve().parents[1] / "robots" / "sk120" / "campaigns" / "table2"
TABLE_TEXT = (TABLE2 / "measurements.csv").read_text()
RIG = "\n".join(BASE_ROWS) + "\n"
UNITS = {"angle": "deg", "force": "N", "length": "mm"}


def _same(a, b, names: tuple[str, ...]) -> None:
    for name in names:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.fixture(scope="module")
def deflections(tmp_path_factory) -> tuple[Path, object]:
    """A copy of the Table II campaign (the working folder) and the campaign it reads as."""
    folder = tmp_path_factory.mktemp("edges-deflections")
    for name in ("campaign.toml", "measurements.csv"):
        shutil.copy(TABLE2 / name, folder / name)
    return folder, load_campaign(folder)


@pytest.fixture(scope="module")
def poses(tmp_path_factory) -> tuple[Path, str, object]:
    """A UR5 pose campaign (three poses of the marker 'tip'), its CSV text and its reading."""
    folder = tmp_path_factory.mktemp("edges-poses")
    write_ur5_tip_campaign(folder)
    return folder, (folder / "measurements.csv").read_text(), load_pose_campaign(folder)


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> tuple[Path, object]:
    folder = tmp_path_factory.mktemp("edges-rig")
    (folder / "rig.csv").write_text(RIG)
    campaign, _ = import_campaign([folder / "rig.csv"], RobotSettings("ur5"),
                                  ImportSettings(units=UNITS))
    return folder, campaign


@contextlib.contextmanager
def _written(path: Path, raw: bytes, text: str) -> Iterator[Path]:
    """``path`` holding ``raw`` for the block, ``text`` again after it."""
    path.write_bytes(raw)
    try:
        yield path
    finally:
        path.write_text(text)


def _read_deflections(folder: Path, raw: bytes):
    with _written(folder / "measurements.csv", raw, TABLE_TEXT):
        return load_campaign(folder)


@EDGES
@given(data=st.data())
def test_a_spreadsheets_campaign_reads_the_same_numbers(deflections, data):
    folder, plain = deflections
    raw = data.draw(spreadsheet_mutation(TABLE_TEXT))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnknownColumnWarning)
        campaign = _read_deflections(folder, raw)
    _same(campaign, plain, ("q", "force", "deflection"))
    assert list(campaign.config) == list(plain.config)


@EDGES
@given(data=st.data())
def test_any_byte_of_a_campaign_reads_or_is_one_line(deflections, data):
    folder, _ = deflections
    raw = data.draw(byte_mutation(TABLE_TEXT))
    with warnings.catch_warnings(), _written(folder / "measurements.csv", raw, TABLE_TEXT):
        warnings.simplefilter("ignore")
        result = assert_reader_contract(lambda: load_campaign(folder), folder)
    if result is not None:
        assert all(np.all(np.isfinite(getattr(result, n))) for n in ("q", "force",
                                                                     "deflection"))


def _read_poses(folder: Path, text: str, raw: bytes):
    with _written(folder / "measurements.csv", raw, text):
        return load_pose_campaign(folder)


@EDGES
@given(data=st.data())
def test_a_trackers_pose_campaign_reads_the_same_numbers(poses, data):
    folder, text, plain = poses
    raw = data.draw(spreadsheet_mutation(text))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnknownColumnWarning)
        campaign = _read_poses(folder, text, raw)
    _same(campaign, plain, ("q", "positions"))
    assert list(campaign.labels) == list(plain.labels)


@EDGES
@given(data=st.data())
def test_any_byte_of_a_pose_campaign_reads_or_is_one_line(poses, data):
    folder, text, _ = poses
    raw = data.draw(byte_mutation(text))
    with warnings.catch_warnings(), _written(folder / "measurements.csv", raw, text):
        warnings.simplefilter("ignore")
        result = assert_reader_contract(lambda: load_pose_campaign(folder), folder)
    if result is not None:
        assert np.all(np.isfinite(result.q))


def _import(folder: Path, raw: bytes | None = None):
    if raw is None:
        return import_campaign([folder / "rig.csv"], RobotSettings("ur5"),
                               ImportSettings(units=UNITS))[0]
    with _written(folder / "rig.csv", raw, RIG):
        return _import(folder)


@EDGES
@given(data=st.data())
def test_a_rigs_export_imports_the_same_numbers(rig, data):
    """The rig import reads names exactly (``Fx [N]`` is no ``fx``: it refuses, naming the
    map): spaces around the names, not their case."""
    folder, plain = rig
    raw = data.draw(spreadsheet_mutation(RIG, case=False))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        campaign = _import(folder, raw)
    _same(campaign, plain, ("q", "force", "deflection"))


@EDGES
@given(data=st.data())
def test_any_byte_of_a_rigs_export_imports_or_is_one_line(rig, data):
    folder, _ = rig
    raw = data.draw(byte_mutation(RIG))
    with warnings.catch_warnings(), _written(folder / "rig.csv", raw, RIG):
        warnings.simplefilter("ignore")
        result = assert_reader_contract(lambda: _import(folder), folder)
    if result is not None:
        assert np.all(np.isfinite(result.q)) and np.all(np.isfinite(result.deflection))


def test_a_units_row_is_the_headers_units_to_the_import(rig, tmp_path):
    """A rig's units row under the header (``deg, ..., N, ..., mm``) reads as units in the
    headers: the same campaign as --units, without --units; a unit that is not the column's
    kind is refused naming the column."""
    _, plain = rig
    header, *rows = BASE_ROWS
    units = ",".join(["deg"] * 6 + ["[N]"] * 3 + ["mm"] * 3)
    path = tmp_path / "rig.csv"
    path.write_text("\n".join([header, units, *rows]) + "\n")
    campaign, _ = import_campaign([path], RobotSettings("ur5"), ImportSettings())
    _same(campaign, plain, ("q", "force", "deflection"))
    path.write_text("\n".join([header, units.replace("deg", "mm", 1), *rows]) + "\n")
    with pytest.raises(Exception, match=r"rig.csv, column 1 \(q1 \[mm\]\): the header says "
                                        r"'mm', not a angle unit"):
        import_campaign([path], RobotSettings("ur5"), ImportSettings())


def test_a_cell_beyond_pythons_csv_limit_is_one_line(deflections, poses, rig):
    """A 200 KB cell (a logger's runaway line) raised _csv.Error, which is no ValueError: a
    traceback; now one line naming the file and the line."""
    from stiffness.errors import FileFormatError

    huge = "1" * 200_000
    for read, folder, text in (
            (lambda raw: _read_deflections(deflections[0], raw), deflections[0], TABLE_TEXT),
            (lambda raw: _read_poses(poses[0], poses[1], raw), poses[0], poses[1]),
            (lambda raw: _import(rig[0], raw), rig[0], RIG)):
        lines = text.splitlines()
        lines[1] = f'"{huge}",' + lines[1]
        with pytest.raises(FileFormatError, match=r", line 2: not CSV \(field larger than "
                                                  r"field limit"):
            read("\n".join(lines).encode())
        assert folder.is_dir()


def _spreadsheet_variants(text: str) -> dict[str, bytes]:
    """Fixed spreadsheet edges of a CSV ``text`` (header first)."""
    header, *rows = text.splitlines()
    return {
        "names in upper case with spaces": "\n".join([",".join(
            f" {c.upper()} " for c in header.split(",")), *rows, ""]).encode(),
        "a comma ending every line": "".join(f"{line},\n" for line in [header, *rows]).encode(),
        "BOM, CRLF, empty rows": ("\ufeff" + "\r\n".join([header, *rows, ",,,,", ""])).encode(),
        "comments": "\n".join(["# logged", header, '# pose 1,"tip seen', *rows, "#", ""]
                              ).encode(),
    }


def test_a_spreadsheets_path_and_plan_read_the_same_numbers(ur5, tmp_path):
    """The joint path (compensate --path) and the plan (simulate --plan) readers too: the
    path's header of joint names in upper case was refused, a comment line read as its
    header; the plan refused 'CONFIG', a comma ending every line ('got ''') and ',,,,' rows."""
    from test_fuzz_readers import DOCS, PLAN, PLAN_UNITS

    from stiffness.machining.joint_path import read_joint_path
    from stiffness.planning.plan import read_plan

    path_text = (DOCS / "ur5-path.csv").read_text()
    plain_path = read_joint_path(DOCS / "ur5-path.csv", ur5, deg=True)
    (tmp_path / "plan.csv").write_text(PLAN_UNITS + PLAN)
    plain_plan, _ = read_plan(tmp_path / "plan.csv", ur5)
    for name, raw in _spreadsheet_variants(path_text).items():
        (tmp_path / "path.csv").write_bytes(raw)
        np.testing.assert_array_equal(read_joint_path(tmp_path / "path.csv", ur5,
                                                      deg=True).coords, plain_path.coords,
                                      err_msg=name)
    for name, raw in _spreadsheet_variants(PLAN).items():
        (tmp_path / "plan.csv").write_bytes(PLAN_UNITS.encode() + raw.removeprefix(
            "\ufeff".encode()))
        plan, _ = read_plan(tmp_path / "plan.csv", ur5)
        _same(plan, plain_plan, tuple(k for k, v in vars(plain_plan).items()
                                      if isinstance(v, np.ndarray)))
        assert plan.config == plain_plan.config, name


def test_a_row_index_before_config_is_named(deflections, poses):
    """pandas' to_csv without index=False writes an unnamed first column of row numbers:
    'the first column must be config, got ''' said what, not why. The pose campaign's header
    errors also named line 1 whatever comments came before the header."""
    from stiffness.errors import FileFormatError

    words = ("got '', an unnamed column before config: a row index (pandas writes one unless "
             "to_csv(index=False)); delete that column")
    for read, text in ((lambda raw: _read_deflections(deflections[0], raw), TABLE_TEXT),
                       (lambda raw: _read_poses(poses[0], poses[1], raw), poses[1])):
        lines = text.splitlines()
        indexed = ["# exported by pandas", "," + lines[0],
                   *(f"{i},{line}" for i, line in enumerate(lines[1:]))]
        with pytest.raises(FileFormatError, match=r"measurements.csv, line 2(, column 1)?: "
                                                  r"the first column must be '?config'?, "):
            read("\n".join(indexed).encode())
        with pytest.raises(FileFormatError) as info:
            read("\n".join(indexed).encode())
        assert words in str(info.value)


def _hashed(text: str, row: int) -> str:
    """``text`` with data row ``row`` (1-based after the header) given a label starting with
    '#', as a rig numbers its rows (``#2``); every other line kept."""
    lines = text.splitlines()
    lines[row] = "#" + lines[row]
    return "\n".join(["# exported 2026-12-05, 3 poses, 2 markers", *lines]) + "\n"


def test_a_row_whose_label_starts_with_a_hash_is_not_dropped_unseen(deflections, poses, rig,
                                                                    ur5, tmp_path):
    """A line starting with '#' is a comment; one holding a whole row of numbers after the
    header (a rig's row label '#2', or a measurement commented out) was dropped without a word
    by every reader: the campaign read one row fewer. Now each reader says so, once, naming
    the line; comment lines of prose stay silent."""
    from test_fuzz_readers import DOCS

    from stiffness.errors import DataFileWarning
    from stiffness.machining.joint_path import read_joint_path

    path_text = (DOCS / "ur5-path.csv").read_text()
    (tmp_path / "rig.csv").write_text(_hashed(RIG, 2))
    (tmp_path / "path.csv").write_text(_hashed(path_text, 2))
    reads = {
        "campaign": lambda: _read_deflections(deflections[0], _hashed(TABLE_TEXT, 2).encode()),
        "poses": lambda: _read_poses(poses[0], poses[1], _hashed(poses[1], 2).encode()),
        "rig": lambda: import_campaign([tmp_path / "rig.csv"], RobotSettings("ur5"),
                                       ImportSettings(units=UNITS)),
        "path": lambda: read_joint_path(tmp_path / "path.csv", ur5, deg=True),
    }
    for name, read in reads.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            read()
        said = [str(w.message) for w in caught if issubclass(w.category, DataFileWarning)
                and "starting with '#'" in str(w.message)]
        assert len(said) == 1, (name, [str(w.message) for w in caught])
        assert "1 line(s) starting with '#' hold a full data row (first: line 4)" in said[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataFileWarning)
        _read_deflections(deflections[0], ("# a comment, 1, 2, 3\n" + TABLE_TEXT + "# end, 4, 5"
                                           ).encode())


#: A rig's rows with decimals in every kind of column (UR5, deg, N, mm).
DECIMAL_RIG = ["label,q1,q2,q3,q4,q5,q6,fx,fy,fz,dx,dy,dz",
               "A,0.5,-90.25,90,0,90,0,10.5,0,-2.25,0.1,0,-0.0125",
               "B,0.5,-80.75,90,0,90,0,0,10.25,0,0.015,0.1,1.5e-3"]


@EDGES
@given(separator=st.sampled_from([";", "\t"]), comma=st.booleans(),
       values=st.lists(st.floats(-1e3, 1e3, allow_nan=False).map(lambda v: round(v, 4)),
                       min_size=3, max_size=3))
def test_a_european_or_tab_separated_export_imports_the_same_numbers(rig, separator, comma,
                                                                     values):
    """A European spreadsheet writes ';' and decimal commas, a tracker's text export tabs:
    the rig import refused both ('the columns are separated by ...'), though nothing in them
    is ambiguous. Now it reads them, to the same campaign as the comma-separated file,
    whatever the numbers (here the first row's deflections drawn)."""
    folder = rig[0]
    rows = [line.split(",") for line in DECIMAL_RIG]
    rows[1][10:13] = [repr(v) for v in values]
    plain = folder / "plain.csv"
    plain.write_text("\n".join(",".join(r) for r in rows) + "\n")
    other = folder / "other.csv"
    other.write_text("\n".join(separator.join(c.replace(".", ",") if comma else c for c in r)
                               for r in rows) + "\n")
    settings = ImportSettings(column_map={"config": "label"}, units=UNITS)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            want, _ = import_campaign([plain], RobotSettings("ur5"), settings)
            got, _ = import_campaign([other], RobotSettings("ur5"), settings)
    finally:
        plain.unlink()
        other.unlink()
    _same(got, want, ("q", "force", "deflection"))
    assert list(got.config) == list(want.config)


def test_decimal_points_beside_decimal_commas_are_refused(tmp_path):
    """';' with decimal commas, but one number written with a point: '1.234' might be a
    thousands separator's 1234, so neither reading is guessed: one line naming the cell."""
    from stiffness.errors import DataFileNote, FileFormatError

    rows = [r.replace(".", ",").replace(",", ";", 12) if i == 0 else ";".join(
        c.replace(".", ",") for c in r.split(",")) for i, r in enumerate(DECIMAL_RIG)]
    path = tmp_path / "rig.csv"
    path.write_text("\n".join(rows) + "\n")
    settings = ImportSettings(column_map={"config": "label"}, units=UNITS)
    with pytest.warns(DataFileNote, match="separated by ';', numbers with a decimal comma"):
        import_campaign([path], RobotSettings("ur5"), settings)
    path.write_text("\n".join(rows).replace("10,5", "10.5") + "\n")
    with pytest.raises(FileFormatError, match=r"rig.csv, line 2, column 8 \(fx\)?.*'10.5' has a "
                                              r"decimal point, but line 2 has a number with a "
                                              "decimal comma"):
        import_campaign([path], RobotSettings("ur5"), settings)


@EDGES
@given(gaps=st.lists(st.sampled_from([" ", "  ", "\t", " \t "]), min_size=24, max_size=24),
       lead=st.sampled_from(["", " ", "  "]),
       values=st.lists(st.floats(-1, 1, allow_nan=False).map(lambda v: f"{v:.18e}"),
                       min_size=3, max_size=3))
def test_a_headerless_space_separated_export_imports_the_same_numbers(rig, gaps, lead, values):
    """``numpy.savetxt`` (a laser tracker's logger, a paper's data set) writes numbers
    separated by spaces and no header. The import took the whole first line for one column's
    name (the first measurement lost) and refused: 'no coordinate column'. Now the columns are
    split at any run of spaces or tabs and, the first row being all numbers, named col1 ..
    colN by position (said in a note): the same campaign as the comma-separated file with a
    header, whatever the gaps and the numbers (the first row's deflections drawn)."""
    from stiffness.errors import DataFileNote

    folder = rig[0]
    rows = [line.split(",") for line in BASE_ROWS]
    rows[1][9:12] = values
    plain = folder / "plain.csv"
    plain.write_text("\n".join(",".join(r) for r in rows) + "\n")
    spaced = folder / "spaced.txt"
    lines = [lead + "".join(c + g for c, g in zip(r, gaps[12 * i:12 * i + 12], strict=True))
             for i, r in enumerate(rows[1:])]
    spaced.write_text("\n".join(lines) + "\n")
    names = rows[0]
    by_position = ImportSettings(column_map={n: f"col{i + 1}" for i, n in enumerate(names)},
                                 units=UNITS)
    try:
        want, _ = import_campaign([plain], RobotSettings("ur5"), ImportSettings(units=UNITS))
        with pytest.warns(DataFileNote, match=r"no header \(line 1 is 12 numbers\): its columns "
                                              r"are named by position, col1 \.\. col12"):
            got, _ = import_campaign([spaced], RobotSettings("ur5"), by_position)
    finally:
        plain.unlink()
        spaced.unlink()
    _same(got, want, ("q", "force", "deflection"))
