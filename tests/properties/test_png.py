"""Property tests of the image readers of ``bop_io`` (``load_depth``, ``load_mask``, ``load_rgb``, ``image_size``)
on PNGs written as :mod:`tests.data.bop_builder` writes them, mutated byte by byte or replaced by another kind."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bop_cender.data.bop_io import image_size, load_depth, load_mask, load_rgb
from tests.properties.mutate import Case, byte_mutations, check

RNG = np.random.default_rng(0)
IMAGES = {
    "depth": (RNG.uniform(6000, 9000, (12, 16))).astype(np.uint16),
    "mask": (np.arange(12 * 16).reshape(12, 16) % 3 == 0).astype(np.uint8) * 255,
    "rgb": RNG.integers(0, 256, (12, 16, 3), dtype=np.uint8),
}


def _png(image: np.ndarray, level: int = 3) -> bytes:
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok
    return buf.tobytes()


READERS: dict[str, Callable[[Path], object]] = {
    "depth": lambda p: load_depth(p, 0.1),
    "mask": load_mask,
    "rgb": load_rgb,
    "size": image_size,
}


def _cases(kind: str) -> st.SearchStrategy[Case]:
    image = IMAGES["rgb" if kind == "size" else kind]
    data = _png(image)
    header_bytes = 24 if kind == "size" else 33  # image_size reads the IHDR alone; a decoder needs it whole

    def truncated(kept: bytes) -> str:
        return "invalid" if len(kept) < header_bytes else "either"  # a lost IEND may still decode

    others = [
        Case(b"", "invalid", "empty file"),
        Case(b"not an image\n", "invalid", "a text file"),
        Case(_png(image)[:8], "invalid", "the PNG signature alone"),
    ]
    if kind == "depth":
        others += [
            Case(_png((image // 256).astype(np.uint8)), "invalid", "an 8-bit depth PNG"),
            Case(_png(np.dstack([image] * 3)), "invalid", "a 3-channel 16-bit PNG"),
            Case(cv2.imencode(".jpg", (image // 256).astype(np.uint8))[1].tobytes(), "invalid", "a JPEG"),
        ]
    same = st.integers(0, 9).map(lambda level: Case(_png(image, level), "same", f"compression level {level}"))
    return st.one_of(same, st.sampled_from(others), byte_mutations(data, truncated).map(_binary))


def _binary(case: Case) -> Case:
    """A byte inserted into a PNG is not a text-encoding matter: undecided (it breaks a chunk's CRC or length)."""
    return Case(case.data, "either", case.what) if case.what.startswith("non-UTF-8") else case


def _values(out: object) -> object:
    return tuple(out) if isinstance(out, tuple) else (np.asarray(out).dtype.str, np.asarray(out).tobytes())


@pytest.mark.parametrize("kind", list(READERS))
@given(data=st.data())
def test_png_readers(kind: str, data: st.DataObject) -> None:
    case = data.draw(_cases(kind), label="case")
    read = READERS[kind]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = root / "000000.png"
        path.write_bytes(_png(IMAGES["rgb" if kind == "size" else kind]))
        reference = _values(read(path))
        path.write_bytes(case.data)
        out = check(case, lambda: read(path), root, path.name, reference, _values)
    if out is not None and kind == "depth":
        assert out.dtype == np.float32 and out.ndim == 2  # type: ignore[attr-defined]
