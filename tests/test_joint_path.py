"""The one joint-path reader (``stiffness.machining.joint_path.read_joint_path``), read by
``compensate``, ``track`` and ``view --path``: a file with a header line naming its columns and
one of rows of numbers alone.

Property tests (hypothesis): a random valid path, written in either form, reads back to the
coordinates written (the numbers' shortest repr, so to the last bit; degrees converted as
``np.deg2rad`` does); a malformed one gives a one-line :class:`StiffnessError`, never a
traceback, and writes nothing (:func:`fuzzing.assert_reader_contract`).
"""

from __future__ import annotations

import numpy as np
import pytest
from fuzzing import FUZZ, NASTY_CELLS, assert_reader_contract, csv_mutation, write_text
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from stiffness.elastic.model import ElasticModel
from stiffness.errors import FileFormatError
from stiffness.machining.compensation import compensate
from stiffness.machining.joint_path import read_joint_path

#: The forms a path file is written in: rows of numbers alone, or a header naming the columns
#: by joint name, by ``q1..qn``, or by joint name with the unit in brackets.
FORMS = ("numbers", "joints", "q", "units")
#: The UR5's coordinate joints, in model order (the robot the paths are of).
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint")


def path_text(values: np.ndarray, form: str, deg: bool, comment: bool) -> str:
    """``values`` (m, 6) as a UR5 path file of ``form`` (a ``#`` comment and a blank line
    first with ``comment``, in the form without a header)."""
    unit = "deg" if deg else "rad"
    header = {"numbers": None, "joints": JOINTS, "q": [f"q{i + 1}" for i in range(6)],
              "units": [f"{j} [{unit}]" for j in JOINTS]}[form]
    lines = [",".join(repr(float(v)) for v in row) for row in values]
    if header is not None:
        return "\n".join([",".join(header), *lines]) + "\n"
    return "\n".join((["# a path", ""] if comment else []) + lines) + "\n"


@st.composite
def valid_paths(draw):
    """(values (m, 6), form, deg, comment) of a UR5 path."""
    values = draw(arrays(np.float64, st.tuples(st.integers(1, 6), st.just(6)),
                         elements=st.floats(-400.0, 400.0, allow_nan=False)))
    return values, draw(st.sampled_from(FORMS)), draw(st.booleans()), draw(st.booleans())


@FUZZ
@given(path=valid_paths())
def test_a_valid_path_reads_back_to_its_numbers(ur5, tmp_path_factory, path):
    values, form, deg, comment = path
    assert tuple(ur5.coordinate_joints) == JOINTS
    file = tmp_path_factory.mktemp("path") / "path.csv"
    write_text(file, path_text(values, form, deg, comment))
    read = read_joint_path(file, ur5, deg=deg)
    np.testing.assert_array_equal(read.coords, np.deg2rad(values) if deg else values)
    first = (3 if comment else 1) if form == "numbers" else 2
    assert read.wrench is None and read.lines == list(range(first, first + len(values)))
    assert len(read.cells) == len(values) and len(read.header) == 6


@FUZZ
@given(path=valid_paths(), data=st.data())
def test_a_malformed_path_is_one_line_never_a_traceback(ur5, tmp_path_factory, path, data):
    """A valid path of either form with one mutation (:func:`fuzzing.csv_mutation`: a column
    dropped, duplicated or renamed, a nasty cell, a truncation, a short or long row, a
    byte-order mark, an empty file): read, or refused in one line."""
    values, form, deg, comment = path
    rows = np.vstack([values, values[:1]])  # two rows at least: one to spoil
    folder = tmp_path_factory.mktemp("bad-path")
    file = folder / "path.csv"
    write_text(file, data.draw(csv_mutation(path_text(rows, form, deg, comment))))
    result = assert_reader_contract(lambda: read_joint_path(file, ur5, deg=deg), folder)
    if result is not None:
        assert np.all(np.isfinite(result.coords)) and result.coords.shape[1] == 6


@pytest.mark.parametrize("cell", [c for c in NASTY_CELLS if "," not in c])
def test_a_nasty_cell_of_a_path_without_header_names_its_line(ur5, tmp_path, cell):
    """Each nasty cell in the second row of a path of numbers alone: read where it is a
    number (``1e-400`` is 0), else refused in one line naming line 2."""
    file = tmp_path / "path.csv"
    write_text(file, f"1,2,3,4,5,6\n1,2,{cell},4,5,6\n")
    try:
        read = read_joint_path(file, ur5)
    except FileFormatError as exc:
        assert "line 2" in str(exc) and "\n" not in str(exc), str(exc)
    else:
        assert np.all(np.isfinite(read.coords)) and read.coords.shape == (2, 6)


def test_compensate_reads_a_path_without_header(ur5, tmp_path):
    """``compensate`` reads the file ``view --path`` reads, rows of numbers alone: the same
    output as the same path with a header naming the joints (its columns named after them)."""
    rows = np.array([[0.1, -1.2, 1.4, -0.3, 1.5, 0.0], [0.2, -1.1, 1.3, -0.4, 1.5, 0.1]])
    plain, named = tmp_path / "plain.csv", tmp_path / "named.csv"
    write_text(plain, path_text(rows, "numbers", False, True))
    write_text(named, path_text(rows, "joints", False, False))
    model = ElasticModel.joint_springs(ur5, [8e4, 6e4, 4e4, 1.2e4, 1.2e4, 1e4])
    a, b = (compensate(model, f, wrench=[0.0, 0.0, -50.0]) for f in (plain, named))
    np.testing.assert_array_equal(a.array("command"), b.array("command"))
    assert a.csv() == b.csv() and a.csv().startswith(",".join(JOINTS) + ",")


def test_a_units_row_under_the_header_is_read_as_the_columns_units(ur5, tmp_path):
    """A spreadsheet's second header line of units ('deg' under every joint): the path reader
    refused it as "'deg' is not a number; every value must be one". It is now read as the
    units in the header are (campaign import's rule): the same path with --deg, and without
    it the refusal names the fix."""
    from pathlib import Path

    docs = Path(__file__).resolve().parents[1] / "docs" / "compensation" / "ur5-path.csv"
    lines = docs.read_text().splitlines()
    plain = read_joint_path(docs, ur5, deg=True)
    path = tmp_path / "path.csv"
    path.write_text("\n".join([lines[0], ",".join(["[deg]"] * 6), *lines[1:]]) + "\n")
    np.testing.assert_array_equal(read_joint_path(path, ur5, deg=True).coords, plain.coords)
    with pytest.raises(FileFormatError, match=r"the header says deg but shoulder_pan_joint is "
                                              "read in rad; give --deg"):
        read_joint_path(path, ur5)
