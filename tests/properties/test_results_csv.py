"""Property tests of the BOP results CSV reader (``read_bop_results``) and of ``bop-cender score`` on a mutated
CSV: a valid file written by ``write_bop_results``, mutated line by line, field by field and byte by byte."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from bop_cender.cli import main
from bop_cender.results.bop_csv import HEADER, BopEstimate, read_bop_results, write_bop_results
from tests.properties.mutate import Case, byte_mutations, check, text_variations

KNOWN = (1, 2, 3)


def _seed_text() -> str:
    """Six rows: two images of scene 1 with three estimates each (the image's time shared), R random rotations."""
    rng = np.random.default_rng(3)
    rows = []
    for im, time_s in ((0, 0.25), (4, -1.0)):
        for k, obj in enumerate(KNOWN):
            R = Rotation.random(random_state=rng).as_matrix()
            rows.append(BopEstimate(1, im, obj, 0.9 - 0.1 * k, R, rng.uniform(-100, 100, 3) + [0, 0, 700], time_s))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m_tless-test.csv"
        write_bop_results(path, rows)
        return path.read_text()


SEED = _seed_text()
LINES = SEED.splitlines()  # LINES[0] is the header
N_FIELDS = 7


def _with_line(k: int, line: str) -> bytes:
    lines = list(LINES)
    lines[k] = line
    return ("\n".join(lines) + "\n").encode()


def _field_edit(k: int, column: int, value: str, what: str) -> Case:
    fields = LINES[k].split(",")
    fields[column] = value
    return Case(_with_line(k, ",".join(fields)), "invalid", f"line {k + 1}: {what}")


@st.composite
def invalid_lines(draw: st.DrawFn, unknown_ids: bool = True) -> Case:
    """One line of the file made invalid in one way (each the reader must refuse); ``unknown_ids``: also an
    obj_id that is not a model (refused where the reader is given the models)."""
    k = draw(st.integers(1, len(LINES) - 1))
    fields = LINES[k].split(",")
    kinds = ["id", "number", "count", "columns", "rotation", "time"] + ["unknown"] * unknown_ids
    kind = draw(st.sampled_from(kinds))
    if kind == "id":
        column = draw(st.integers(0, 2))
        value = draw(st.sampled_from(["-1", "1.5", "x", "", "1e3", "+1", "٣", "99999999999999999999", "nan", "0x1"]))
        return _field_edit(k, column, value, f"id column {column} = {value!r}")
    if kind == "number":
        column = draw(st.integers(3, 6))
        tokens = fields[column].split()
        i = draw(st.integers(0, len(tokens) - 1))
        tokens[i] = draw(st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "x", "1,5", "--1", "0x10"]))
        return _field_edit(k, column, " ".join(tokens), f"column {column} token {i} = {tokens[i]!r}")
    if kind == "count":
        column = draw(st.sampled_from([3, 4, 5, 6]))
        tokens = fields[column].split()
        tokens = tokens[:-1] if draw(st.booleans()) else [*tokens, "1.0"]
        return _field_edit(k, column, " ".join(tokens), f"column {column} with {len(tokens)} numbers")
    if kind == "columns":
        n = draw(st.sampled_from([1, 6, 8, 9]))
        line = ",".join((fields + ["1"] * 3)[:n])
        return Case(_with_line(k, line), "invalid", f"line {k + 1} with {n} columns")
    if kind == "rotation":
        R = np.array(fields[4].split(), dtype=float).reshape(3, 3)
        how = draw(st.sampled_from(["scaled", "reflection", "zeros", "random"]))
        bad = {"scaled": R * 1.1, "reflection": -R, "zeros": 0 * R,
               "random": np.random.default_rng(k).normal(size=(3, 3))}[how]  # fmt: skip
        return _field_edit(k, 4, " ".join(map(repr, bad.ravel().tolist())), f"R {how}")
    if kind == "unknown":
        return _field_edit(k, 2, draw(st.sampled_from(["0", "4", "999"])), "unknown obj_id")
    time_s = float(fields[6])
    if time_s < 0:  # an unknown time: another row's known time would not disagree with it
        return _field_edit(k, 0, "-2", "scene_id -2")
    return _field_edit(k, 6, repr(time_s + 1.0), "a time other than the image's")


def _undecided(kept: bytes) -> str:
    return "either"  # a cut at a line end is a shorter valid file; inside a number it may still parse


@st.composite
def valid_rewrites(draw: st.DrawFn) -> Case:
    """The same rows written otherwise: no header, spaces around fields and numbers, then CRLF / BOM / ..."""
    lines = list(LINES)
    if draw(st.booleans()):
        lines = lines[1:]
    pad = draw(st.sampled_from(["", " ", "  ", "\t"]))
    lines = [ln if ln == HEADER else ",".join(f"{pad}{f}{pad}" for f in ln.split(",")) for ln in lines]
    base = draw(text_variations("\n".join(lines) + "\n"))
    return Case(base.data, "same", f"header={lines[0] == HEADER} pad={pad!r} {base.what}")


CASES = st.one_of(
    text_variations(SEED),
    valid_rewrites(),
    invalid_lines(),
    byte_mutations(SEED.encode(), _undecided),
    st.integers(1, len(LINES) - 2).map(lambda n: Case(_with_line(n, ""), "invalid", f"line {n + 1} empty (not last)")),
)


def _values(rows: list[BopEstimate]) -> list[tuple]:
    return [(r.scene_id, r.im_id, r.obj_id, r.score, r.R.tobytes(), r.t.tobytes(), r.time) for r in rows]


@given(case=CASES)
def test_results_csv_reader(case: Case) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = root / "m_tless-test.csv"
        path.write_text(SEED)
        reference = _values(read_bop_results(path, KNOWN))
        path.write_bytes(case.data)
        check(case, lambda: read_bop_results(path, KNOWN), root, str(path), reference, _values)


INVALID = st.one_of(
    invalid_lines(unknown_ids=False),  # score checks the ids against the data, which it opens after the CSV
    st.builds(
        lambda k: Case(SEED.encode()[:k] + b"\xff" + SEED.encode()[k:], "invalid", f"\\xff at byte {k}"),
        st.integers(0, len(SEED)),
    ),  # fmt: skip
)


@settings(max_examples=25)
@given(case=INVALID)
def test_score_command_on_a_mutated_csv(case: Case, capsys: pytest.CaptureFixture[str]) -> None:
    """``bop-cender score`` on an invalid CSV: exit 2, one ``error:`` line naming the file (followed by the bad
    lines it lists, each indented), no traceback, and no file written."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        csv_path = root / "gt_tless-test.csv"
        csv_path.write_bytes(case.data)
        capsys.readouterr()
        assert main(["score", str(csv_path), "--data-root", str(root / "no-data"), "--no-progress"]) == 2
        err = capsys.readouterr().err.splitlines()
        assert err and err[0].startswith(f"error: {csv_path}: "), (case.what, err)
        assert all(line.startswith("  line ") for line in err[1:]), (case.what, err)
        assert "Traceback" not in "\n".join(err)
        assert sorted(p.name for p in root.iterdir()) == [csv_path.name], case.what
