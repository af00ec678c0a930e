"""Property tests of the two PLY readers: the loader's (``load_ply``, trimesh and the shared checks) and the
scorer's fast ASCII reader (``ply_ascii.ascii_mesh`` / ``ascii_vertices``, what ``eval_vertices`` reads), on
model files written as :mod:`tests.data.bop_builder` writes them (``save_ply``), mutated."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
from hypothesis import given
from hypothesis import strategies as st

from bop_cender.data.bop_io import load_ply, save_ply
from bop_cender.data.ply_ascii import _ascii_ply, ascii_mesh, ascii_vertices
from tests.properties.mutate import Case, byte_mutations, check


def _seed() -> str:
    mesh = trimesh.creation.box(extents=(50.0, 30.0, 20.0))  # the builder's obj 2: 8 vertices, 12 triangles
    with tempfile.TemporaryDirectory() as tmp:
        save_ply(Path(tmp) / "m.ply", mesh)
        return (Path(tmp) / "m.ply").read_text()


SEED = _seed()
HEAD, BODY = SEED.split("end_header\n")
HEAD_LINES = (HEAD + "end_header").split("\n")
BODY_LINES = BODY.splitlines()
N_VERTS = int(next(h for h in HEAD_LINES if h.startswith("element vertex")).split()[-1])


def _file(head: list[str], body: list[str], sep: str = "\n", final: bool = True) -> bytes:
    return (sep.join(head + body) + (sep if final else "")).encode()


@st.composite
def variations(draw: st.DrawFn) -> Case:
    """CRLF, no final newline, runs of spaces or tabs between values: the same mesh."""
    crlf, final = draw(st.booleans()), draw(st.booleans())
    gap = draw(st.sampled_from([" ", "  ", "\t", " \t "]))
    body = [gap.join(line.split()) for line in BODY_LINES]
    return Case(
        _file(HEAD_LINES, body, "\r\n" if crlf else "\n", final), "same", f"crlf={crlf} final={final} gap={gap!r}"
    )


@st.composite
def invalid(draw: st.DrawFn) -> Case:
    """One change no reader may accept."""
    body = list(BODY_LINES)
    head = list(HEAD_LINES)
    kind = draw(st.sampled_from(["nan", "word", "index", "short", "count", "header", "magic", "noface"]))
    if kind in ("nan", "word"):
        v, c = draw(st.integers(0, N_VERTS - 1)), draw(st.integers(0, 2))
        values = body[v].split()
        values[c] = draw(st.sampled_from(["nan", "inf", "-inf", "NaN"] if kind == "nan" else ["x", "1..0", "--2", ""]))
        body[v] = " ".join(values)
        what = f"vertex {v} coordinate {c} = {values[c]!r}"
    elif kind == "index":
        f = draw(st.integers(N_VERTS, len(body) - 1))
        idx = body[f].split()
        i = draw(st.integers(1, 3))
        idx[i] = str(draw(st.sampled_from([N_VERTS, N_VERTS + 5, -1, 10**9])))
        body[f] = " ".join(idx)
        what = f"face line {f} index {i} = {idx[i]}"
    elif kind == "short":
        v = draw(st.integers(0, N_VERTS - 1))
        body[v] = " ".join(body[v].split()[:-1])
        what = f"vertex {v} one value short"
    elif kind == "count":
        element = draw(st.sampled_from(["element vertex", "element face"]))
        k = next(i for i, h in enumerate(head) if h.startswith(element))
        words = head[k].split()
        words[2] = str(int(words[2]) + draw(st.integers(1, 5)))
        head[k] = " ".join(words)
        what = f"{head[k]!r}: more than the file holds"
    elif kind == "header":
        head = [h for h in head if h != "end_header"]
        what = "no end_header"
    elif kind == "magic":
        head[0] = draw(st.sampled_from(["PLY", "ply2", "", "solid"]))
        what = f"first line {head[0]!r}"
        if head[0]:  # trimesh takes any first line containing 'ply' (case-insensitive) for the magic
            return Case(_file(head, body), "invalid" if "ply" not in head[0].lower() else "either", what)
    else:
        head = [h for h in head if not h.startswith(("element face", "property list"))]
        body = body[:N_VERTS]
        what = "no faces"  # refused by load_ply; the ASCII reader gives the vertices (all MSSD / MSPD need)
    return Case(_file(head, body), "invalid", what)


def _truncated(kept: bytes) -> str:
    """Cut before the last line starts: lines are missing (refused); inside the last line: undecided."""
    return "invalid" if len(kept) <= len(SEED.encode()) - len(BODY_LINES[-1]) - 2 else "either"


CASES = st.one_of(variations(), invalid(), byte_mutations(SEED.encode(), _truncated))


def _adjust(case: Case, faces_needed: bool) -> Case:
    """A non-UTF-8 byte in a PLY: in the header it is decoded leniently, in the body it is no number: undecided.
    A PLY without faces: refused where a mesh is needed (``faces_needed``), else its vertices are enough."""
    if (
        case.what.startswith("non-UTF-8") or (case.what == "no faces" and not faces_needed)
    ) and case.expect == "invalid":
        return Case(case.data, "either", case.what)
    return case


def _prop(read: Callable[[Path], object], compare: Callable[[object], object], faces: bool) -> Callable[..., None]:
    def run(case: Case) -> None:
        case = _adjust(case, faces)
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            path = root / "obj_000002.ply"
            path.write_text(SEED)
            _ascii_ply.cache_clear()
            reference = compare(read(path))
            path.write_bytes(case.data)
            _ascii_ply.cache_clear()
            out = check(case, lambda: read(path), root, path.name, reference, compare)
        if out is not None and case.expect != "invalid":
            assert np.isfinite(np.asarray(compare(out)[0])).all()

    return given(case=CASES)(run)


def _arrays(mesh: object) -> tuple:
    return (np.asarray(mesh.vertices).tolist(), np.asarray(mesh.faces).tolist())  # type: ignore[attr-defined]


def _ascii_read(path: Path) -> object:
    """What the scorer reads: the ASCII reader's vertices, and trimesh's where it declines (None: not ASCII)."""
    mesh = ascii_mesh(path)
    vertices = ascii_vertices(str(path.resolve()))
    if vertices is None:
        return load_ply(path)
    assert mesh is None or np.array_equal(mesh.vertices, vertices)  # the two entry points agree
    return mesh if mesh is not None else trimesh.Trimesh(vertices, np.zeros((0, 3), int), process=False)


test_load_ply = _prop(load_ply, _arrays, faces=True)
test_ascii_ply = _prop(_ascii_read, _arrays, faces=False)


# ------------------------------------------------------------------------------------------ binary PLY (load_ply)


def _binary_seed() -> bytes:
    mesh = trimesh.creation.box(extents=(50.0, 30.0, 20.0))
    return trimesh.exchange.ply.export_ply(mesh, encoding="binary")


BINARY = _binary_seed()
BINARY_BODY = BINARY.index(b"end_header\n") + len(b"end_header\n")


@st.composite
def binary_invalid(draw: st.DrawFn) -> Case:
    """A NaN or infinite coordinate, or a face index beyond the vertices, in a binary little-endian PLY."""
    out = bytearray(BINARY)
    if draw(st.booleans()):
        v, c = draw(st.integers(0, 7)), draw(st.integers(0, 2))
        value = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        at = BINARY_BODY + 12 * v + 4 * c
        out[at : at + 4] = np.float32(value).tobytes()
        return Case(bytes(out), "invalid", f"binary vertex {v} coordinate {c} = {value}")
    f, i = draw(st.integers(0, 11)), draw(st.integers(0, 2))
    at = BINARY_BODY + 12 * 8 + 13 * f + 1 + 4 * i  # a face: uchar count 3, then three int32
    out[at : at + 4] = np.int32(draw(st.sampled_from([8, 9, 1000, -1]))).tobytes()
    return Case(bytes(out), "invalid", f"binary face {f} index {i} out of range")


def _binary_truncated(kept: bytes) -> str:
    return "invalid"  # any cut of a binary PLY loses vertex or face bytes


def _binary_case(case: Case) -> Case:
    """A byte that is not UTF-8, inserted into a binary body, is data: undecided (in the header: refused or read)."""
    return Case(case.data, "either", case.what) if case.what.startswith("non-UTF-8") else case


@given(case=st.one_of(binary_invalid(), byte_mutations(BINARY, _binary_truncated)))
def test_load_ply_binary(case: Case) -> None:
    """A binary PLY, as CAD exporters write them: the loader's checks hold for it too."""
    case = _binary_case(case)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = root / "obj_000002.ply"
        path.write_bytes(BINARY)
        reference = _arrays(load_ply(path))
        path.write_bytes(case.data)
        out = check(case, lambda: load_ply(path), root, path.name, reference, _arrays)
    if out is not None:
        assert np.isfinite(np.asarray(out.vertices)).all()
        assert int(np.asarray(out.faces).max()) < len(out.vertices)
