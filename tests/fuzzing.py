"""The reader contract and mutations of valid files, shared by the fuzz tests.

The contract (:func:`assert_reader_contract`): a reader given any input either returns (the
test then checks the meaning) or raises a :class:`~stiffness.errors.StiffnessError` whose
message is one line. It never raises another exception and never writes a file. No
per-example deadline: speed lives in scripts/bench.py, never in a test (a reader example took
7.8 s against a 5 s deadline on a loaded 2-core machine, then 222 ms on the retry); a reader
that hung would stop the suite itself.

Examples: a few dozen per reader in CI, thousands with
``HYPOTHESIS_PROFILE=long python -m pytest tests/test_fuzz_readers.py`` (:data:`FUZZ`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from hypothesis import settings
from hypothesis import strategies as st

from stiffness.errors import StiffnessError

#: Settings of every fuzz test: a few dozen examples, thousands under the ``long`` profile
#: (profiles: tests/conftest.py; no deadline, as there).
LONG = os.environ.get("HYPOTHESIS_PROFILE") == "long"
FUZZ = settings(max_examples=2000 if LONG else 40, deadline=None)

#: Cell values that break naive readers.
NASTY_CELLS = ["nan", "NaN", "inf", "-inf", "1e309", "-1e309", "", " ", "1,5", "0x1F", "1e-400",
               "１２", "١٢", "12abc", "--1", "None", "null", "true", "\u00e9", "\u202e12",
               "1" * 400, "9" * 40, "\x00", "'1'", '"1"', "1_000", "+", "."]
#: TOML values of the wrong type for any key.
NASTY_TOML = ['""', "1", "-1", "0", "1e999", "nan", "inf", "[]", "[1, \"a\"]", "{}", "true",
              '"\u00e9\u00e8"', '"' + "x" * 300 + '"', "[[1]]", '"../../etc/passwd"',
              "1979-05-27"]


def files_under(folder: Path) -> dict[str, float]:
    return {str(p): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def assert_reader_contract(read: Callable[[], object], folder: Path) -> object | None:
    """Call ``read()``; allow a result or a one-line StiffnessError, and no new file."""
    before = files_under(folder)
    try:
        result = read()
    except StiffnessError as exc:
        message = str(exc)
        assert message.strip(), "an error with no message"
        assert "\n" not in message.strip(), f"a message of several lines: {message!r}"
        result = None
    after = files_under(folder)
    assert after == before, f"the reader wrote files: {set(after) ^ set(before)}"
    return result


@st.composite
def csv_mutation(draw, text: str) -> str:
    """A mutation of a CSV text: a dropped, duplicated or renamed column, a nasty cell,
    a truncation, a blank or duplicated line, or an empty file."""
    lines = text.splitlines()
    header = lines[0].split(",")
    kind = draw(st.sampled_from(["drop", "duplicate", "rename", "cell", "truncate", "empty",
                                 "blank", "extra_cell", "short_row", "reorder", "bom"]))
    rows = [line.split(",") for line in lines]
    if kind in ("drop", "duplicate", "rename", "reorder"):
        col = draw(st.integers(0, len(header) - 1))
        if kind == "drop":
            rows = [r[:col] + r[col + 1:] for r in rows]
        elif kind == "duplicate":
            rows = [r + [r[col]] for r in rows]
        elif kind == "rename":
            rows[0][col] = draw(st.sampled_from(["", "Q1", "fx ", "dX", "q99", "\u00e9"]))
        else:
            other = draw(st.integers(0, len(header) - 1))
            for r in rows:
                r[col], r[other] = r[other], r[col]
    elif kind == "cell":
        row = draw(st.integers(1, len(rows) - 1))
        col = draw(st.integers(0, len(header) - 1))
        rows[row][col] = draw(st.sampled_from(NASTY_CELLS) | st.text(max_size=8))
    elif kind == "extra_cell":
        rows[draw(st.integers(1, len(rows) - 1))].append("1.0")
    elif kind == "short_row":
        row = draw(st.integers(1, len(rows) - 1))
        rows[row] = rows[row][:-1]
    out = "\n".join(",".join(r) for r in rows) + "\n"
    if kind == "truncate":
        out = text[:draw(st.integers(0, len(text) - 1))]
    elif kind == "empty":
        out = ""
    elif kind == "blank":
        at = draw(st.integers(1, len(lines)))
        out = "\n".join(lines[:at] + ["", lines[at - 1]] + lines[at:]) + "\n"
    elif kind == "bom":
        out = "\ufeff" + text
    return out


@st.composite
def toml_mutation(draw, text: str) -> str:
    """A mutation of a TOML text: a value of the wrong type, a dropped or unknown key, a
    truncation, a duplicated table, invalid UTF-8 or an empty file."""
    lines = text.splitlines()
    assignments = [i for i, line in enumerate(lines)
                   if "=" in line and not line.lstrip().startswith("#")]
    kind = draw(st.sampled_from(["value", "drop", "unknown", "truncate", "empty", "table",
                                 "binary"]))
    if kind == "value" and assignments:
        i = draw(st.sampled_from(assignments))
        key = lines[i].split("=", 1)[0]
        lines[i] = f"{key}= {draw(st.sampled_from(NASTY_TOML))}"
    elif kind == "drop" and assignments:
        del lines[draw(st.sampled_from(assignments))]
    elif kind == "unknown":
        lines.insert(draw(st.integers(0, len(lines))), "colour = \"blue\"")
    elif kind == "table":
        lines.append("[units]")
        lines.append('length = "mm"')
    out = "\n".join(lines) + "\n"
    if kind == "truncate":
        out = text[:draw(st.integers(0, len(text) - 1))]
    elif kind == "empty":
        out = ""
    elif kind == "binary":
        out = text[:draw(st.integers(0, len(text)))] + "\udcff"
    return out


def write_text(path: Path, text: str) -> None:
    """Write ``text`` as UTF-8, surrogate escapes as the raw (invalid UTF-8) bytes."""
    path.write_bytes(text.encode("utf-8", errors="surrogateescape"))


def json_mutations(doc: object) -> st.SearchStrategy:
    """Strategies replacing one node of a JSON document by a value of another type."""
    paths = []

    def walk(node, path):
        paths.append(path)
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, (*path, k))
        elif isinstance(node, list):
            for i, v in enumerate(node[:4]):
                walk(v, (*path, i))

    walk(doc, ())
    nasty = st.sampled_from([None, "", "x", -1, 0, 1e308, [], {}, [None], True, "nan",
                             "\u00e9", [1, "a"], {"a": 1}])
    return st.tuples(st.sampled_from(paths), nasty)


def replaced(doc, path, value):
    """A copy of the JSON ``doc`` with the node at ``path`` set to ``value``."""
    if not path:
        return value
    copy = json.loads(json.dumps(doc))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return copy


#: Comment lines a rig's export may carry: an unbalanced quote, commas, an indented one.
COMMENTS = ["# exported 2026-12-05 14:03", '# operator "R. Smith', '# pose 1,"tip seen', "#",
            "  # indented"]
#: Bytes that break naive readers: separators, quotes, line ends, NUL, a byte-order mark's
#: and invalid UTF-8's.
NASTY_BYTES = b',;"\r\n\t #.-+eE0\x00\xff\xfe\xef\xbb\xbf\xc3'


@st.composite
def spreadsheet_mutation(draw, text: str, case: bool = True) -> bytes:
    """What a spreadsheet or a rig's logger makes of a valid CSV ``text`` that a person still
    reads as the same table: header names in another case (with ``case``) or with spaces
    around them, a comma ending every line, comment lines anywhere, blank or empty (``,,,``)
    rows at the end, Windows line ends, a byte-order mark; as the bytes of the file."""
    lines = text.splitlines()
    header = lines[0].split(",")
    if case:
        header = [draw(st.sampled_from([h, h.upper(), h.title()])) for h in header]
    header = [draw(st.sampled_from([h, f" {h}", f"{h} ", f"  {h}  "])) for h in header]
    lines[0] = ",".join(header)
    if draw(st.booleans()):
        lines = [line + "," for line in lines]
    for _ in range(draw(st.integers(0, 3))):
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(COMMENTS)))
    lines += draw(st.lists(st.sampled_from(["", "  ", ",,,", "," * len(header)]), max_size=3))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    out = end.join(lines) + end
    return (("\ufeff" if draw(st.booleans()) else "") + out).encode()


@st.composite
def byte_mutation(draw, text: str) -> bytes:
    """A valid CSV ``text``'s bytes with one to four bytes replaced, inserted or deleted (a
    separator, a quote, a line end, NUL, invalid UTF-8, or any byte)."""
    raw = bytearray(text.encode())
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["replace", "insert", "delete"]))
        byte = draw(st.sampled_from(list(NASTY_BYTES)) | st.integers(0, 255))
        if kind == "insert" or not raw:
            raw.insert(draw(st.integers(0, len(raw))), byte)
        elif kind == "replace":
            raw[draw(st.integers(0, len(raw) - 1))] = byte
        else:
            del raw[draw(st.integers(0, len(raw) - 1))]
    return bytes(raw)
