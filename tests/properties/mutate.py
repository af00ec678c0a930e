"""Mutations of valid input files, and the one property every reader must hold on them.

A :class:`Case` is a file's bytes after one mutation of a valid seed, with what a reader must do with it:

- ``same``: a valid variation (CRLF, UTF-8 BOM, no final newline, key order, whitespace): accepted, with
  the same values as the seed;
- ``invalid``: refused with exactly one :class:`~bop_cender.errors.BopCenderError` naming the file;
- ``either``: the mutation decides neither (a flipped byte, a number changed to another number):
  accepted, or one BopCenderError, never another exception.

In every case nothing is written to disk (:func:`check`). The strategies here are generic (text,
bytes, JSON trees); each test module adds the mutations that only its format has.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from hypothesis import event
from hypothesis import strategies as st

from bop_cender.errors import BopCenderError

Expect = Literal["same", "invalid", "either"]
JsonPath = tuple[str | int, ...]


@dataclass(frozen=True)
class Case:
    """A mutated file: its bytes, what the reader must do, and what the mutation was."""

    data: bytes
    expect: Expect
    what: str


# ---------------------------------------------------------------------------------------------- byte and text


def text_variations(text: str, *, blank_lines: bool = True) -> st.SearchStrategy[Case]:
    """Valid variations of a text file: CRLF, a UTF-8 BOM, no final newline, trailing blank lines, combined."""

    def build(crlf: bool, bom: bool, strip_final: bool, extra: int) -> Case:
        out = text.rstrip("\n") if strip_final else text
        if extra:
            out = out.rstrip("\n") + "\n" * (extra + 1)
        if crlf:
            out = out.replace("\n", "\r\n")
        data = ("\ufeff" if bom else "") + out
        what = f"variation crlf={crlf} bom={bom} no-final-newline={strip_final} blank-lines={extra}"
        return Case(data.encode("utf-8"), "same", what)

    return st.builds(build, st.booleans(), st.booleans(), st.booleans(), st.integers(0, 2 if blank_lines else 0))


def byte_mutations(data: bytes, truncated: Callable[[bytes], Expect]) -> st.SearchStrategy[Case]:
    """Truncation at a random byte (``truncated(kept)`` says what is expected), a flipped byte (either), a
    byte that is not UTF-8 inserted (invalid for a text file; callers of binary formats override), an empty
    file (as ``truncated(b"")``)."""
    n = len(data)

    def truncate(k: int) -> Case:
        kept = data[:k]
        return Case(kept, truncated(kept), f"truncated at byte {k} of {n}")

    def flip(k: int, mask: int) -> Case:
        out = bytearray(data)
        out[k] ^= mask
        return Case(bytes(out), "either", f"byte {k} xor {mask:#x}")

    def non_utf8(k: int, byte: bytes) -> Case:
        return Case(data[:k] + byte + data[k:], "invalid", f"non-UTF-8 byte {byte!r} inserted at {k}")

    return st.one_of(
        st.builds(truncate, st.integers(0, n - 1)),
        st.builds(flip, st.integers(0, n - 1), st.integers(1, 255)),
        st.builds(non_utf8, st.integers(0, n), st.sampled_from([b"\xff", b"\xfe", b"\xc3", b"\x80", b"\xed\xa0\x80"])),
    )


# ---------------------------------------------------------------------------------------------- JSON trees


def json_paths(tree: Any, prefix: JsonPath = ()) -> list[JsonPath]:
    """Every path below the root of a JSON tree (dict keys and list indices), depth first."""
    out: list[JsonPath] = []
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for k, v in items:
        out.append((*prefix, k))
        out.extend(json_paths(v, (*prefix, k)))
    return out


def _parent(tree: Any, path: JsonPath) -> Any:
    for k in path[:-1]:
        tree = tree[k]
    return tree


def replaced(tree: Any, path: JsonPath, value: Any) -> Any:
    out = json.loads(json.dumps(tree))
    _parent(out, path)[path[-1]] = value
    return out


def deleted(tree: Any, path: JsonPath) -> Any:
    out = json.loads(json.dumps(tree))
    del _parent(out, path)[path[-1]]
    return out


def renamed(tree: Any, path: JsonPath, key: str) -> Any:
    """The dict at ``path[:-1]`` with key ``path[-1]`` renamed to ``key`` (in place in the key order)."""
    out = json.loads(json.dumps(tree))
    parent = _parent(out, path)
    items = [(key if k == path[-1] else k, v) for k, v in parent.items()]
    parent.clear()
    parent.update(items)
    return out


def dumps(tree: Any) -> bytes:
    """JSON with NaN / Infinity written as Python's json writes them (its reader accepts them)."""
    return json.dumps(tree, allow_nan=True).encode("utf-8")


#: Values that are never a number, a finite number or a well-formed array.
BAD_VALUES: tuple[Any, ...] = (None, True, False, "x", "", [], {}, [[]], math.nan, math.inf, -math.inf, {"a": 1})
#: Numbers that may or may not be acceptable where a number is (decided by the field).
OTHER_NUMBERS: tuple[Any, ...] = (0, -1, 0.5, -0.5, 1e308, -1e308, 10**30, 7, 1.0000001, "1", "2.5", 1e-300)
#: Keys that are not image / object ids, and ones that may be.
BAD_KEYS = ("x", "", " ", "1.5", "1e3", "None", "²", "٣", "-", "0x1")
ODD_KEYS = ("-1", "00", "01", "99999999999999999999", "123456")

#: ``strict(path, op)``: True when this op at this path must be refused (op: ``delete``, ``bad``).
Strict = Callable[[JsonPath, str], bool]


def json_path_mutations(tree: Any, strict: Strict) -> st.SearchStrategy[Case]:
    """One change at one node of the tree: deleted, given a bad value (None, a bool, a string, NaN, inf, an
    empty list, ...), given another number, or (a dict key) renamed. Refused where ``strict`` says so."""
    paths = json_paths(tree)

    @st.composite
    def mutate(draw: st.DrawFn) -> Case:
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["delete", "bad", "number", "rename"]))
        parent = _parent(tree, path)
        if op == "rename" and not isinstance(parent, dict):
            op = "bad"
        if op == "delete":
            return Case(dumps(deleted(tree, path)), "invalid" if strict(path, "delete") else "either", f"del {path}")
        if op == "bad":
            value = draw(st.sampled_from(BAD_VALUES))
            expect: Expect = "invalid" if strict(path, "bad") else "either"
            return Case(dumps(replaced(tree, path, value)), expect, f"{path} = {value!r}")
        if op == "number":
            value = draw(st.sampled_from(OTHER_NUMBERS))
            return Case(dumps(replaced(tree, path, value)), "either", f"{path} = {value!r}")
        key = draw(st.sampled_from(BAD_KEYS + ODD_KEYS) | st.text(max_size=4))
        if key in parent:
            key = f"{key}~"
        bad_key = key in BAD_KEYS or not key.strip().lstrip("-").isdigit()
        expect = "invalid" if bad_key and strict(path, "rename") else "either"
        return Case(dumps(renamed(tree, path, key)), expect, f"rename {path} -> {key!r}")

    return mutate()


def json_variations(tree: Any) -> st.SearchStrategy[Case]:
    """The same content written otherwise: indented or not, other separators, every object's keys reordered."""

    @st.composite
    def variation(draw: st.DrawFn) -> Case:
        indent = draw(st.sampled_from([None, 0, 1, 2, 4, "\t"]))
        separators = draw(st.sampled_from([(",", ":"), (", ", ": "), (" , ", " : ")]))
        seed = draw(st.integers(0, 2**16))
        rng = np.random.default_rng(seed)

        def shuffle(node: Any) -> Any:
            if isinstance(node, dict):
                keys = list(node)
                rng.shuffle(keys)
                return {k: shuffle(node[k]) for k in keys}
            if isinstance(node, list):
                return [shuffle(v) for v in node]
            return node

        text = json.dumps(shuffle(tree), indent=indent, separators=separators)
        return Case(
            text.encode("utf-8"), "same", f"reformatted indent={indent!r} separators={separators} keys shuffled"
        )

    return variation()


def json_truncated(original: bytes) -> Callable[[bytes], Expect]:
    """A JSON document cut short: the same where only trailing whitespace went, else refused (an object or
    list without its closing bracket is never JSON)."""
    return lambda kept: "same" if kept.rstrip() == original.rstrip() else "invalid"


def json_cases(tree: Any, strict: Strict, *extra: st.SearchStrategy[Case]) -> st.SearchStrategy[Case]:
    """Every generic mutation of a JSON file written from ``tree`` (as the project's save_json writes it)."""
    from bop_cender.data.bop_io import dumps_bop_json

    text = dumps_bop_json(tree) + "\n"
    data = text.encode("utf-8")
    return st.one_of(
        text_variations(text),
        json_variations(tree),
        json_path_mutations(tree, strict),
        byte_mutations(data, json_truncated(data)),
        *extra,
    )


# ---------------------------------------------------------------------------------------------- the property


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root``: (size, mtime in ns), to tell that a reader wrote nothing."""
    out = {}
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            p = Path(dirpath) / name
            st_ = p.stat()
            out[str(p.relative_to(root))] = (st_.st_size, st_.st_mtime_ns)
    return out


def canon(value: Any, root: Path | None = None) -> Any:
    """A comparable form of a reader's output: dataclasses by field, arrays by dtype/shape/bytes, paths relative
    to ``root`` (so two copies of the same files compare equal)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (type(value).__name__, {f.name: canon(getattr(value, f.name), root) for f in dataclasses.fields(value)})
    if isinstance(value, np.ndarray):
        return ("array", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, Path):
        return str(value.relative_to(root)) if root is not None and value.is_relative_to(root) else str(value)
    if isinstance(value, str) and root is not None and value.startswith(str(root)):
        return value[len(str(root)) :]
    if isinstance(value, Mapping):
        return {"__map__": sorted(((repr(k), canon(v, root)) for k, v in value.items()), key=lambda kv: kv[0])}
    if isinstance(value, list | tuple):
        return [canon(v, root) for v in value]
    if isinstance(value, frozenset | set):
        return sorted(canon(v, root) for v in value)
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return value


def check(
    case: Case,
    read: Callable[[], Any],
    root: Path,
    names: str | tuple[str, ...],
    reference: Any = None,
    compare: Callable[[Any], Any] | None = None,
) -> Any:
    """The property: ``read()`` on the case's file (already written under ``root``) does what ``case.expect``
    says; a refusal is one BopCenderError whose message names the file (one of ``names``, a file name or a
    path); any other exception fails; nothing under ``root`` changes.

    Args:
        reference: ``compare`` of the unmutated file's output; a ``same`` case must give it again.
        compare: the comparable form of an output (default :func:`canon` relative to ``root``).

    Returns:
        the output (None when refused).
    """
    names = (names,) if isinstance(names, str) else names
    before = snapshot(root)
    out = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rounded poses and the like: warnings, not errors
        try:
            out = read()
        except BopCenderError as e:
            message = str(e)
            event(f"expected {case.expect}: refused")
            assert case.expect != "same", f"a valid variation ({case.what}) was refused: {message}"
            assert e.file, f"{case.what}: the error names no file: {message}"
            assert any(n in message for n in names), f"{case.what}: the error does not name {names}: {message}"
        except Exception as e:  # noqa: BLE001  (the property: never anything else)
            raise AssertionError(f"{case.what}: {type(e).__name__}: {e} (expected one BopCenderError)") from e
        else:
            event(f"expected {case.expect}: accepted")
            assert case.expect != "invalid", f"invalid input accepted ({case.what})"
            if case.expect == "same" and reference is not None:
                got = (compare or (lambda o: canon(o, root)))(out)
                assert got == reference, f"a valid variation ({case.what}) read as other values"
    assert snapshot(root) == before, f"{case.what}: the reader changed files under {root}"
    return out
