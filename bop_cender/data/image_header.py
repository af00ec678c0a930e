"""Size, bit depth and channels of a PNG or JPEG read from its header, without decoding a pixel.

``bop-cender info`` checks every image of a split before ``run`` and ``score`` read them; decoding all of
them (T-LESS test: 20 000 files) takes over a minute on two cores, reading their first bytes about two seconds. The header
says what the decoders would return (the size, 16-bit or 8-bit, grey or colour), so a wrong-size image
or an 8-bit depth image is caught without decoding; a file whose pixels are damaged behind a good
header is caught only by decoding it (``info --deep``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bop_cender.errors import DatasetError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG colour type -> channels as decoded unchanged (palette images decode to colour).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}
#: JPEG start-of-frame markers (baseline, progressive, ...): all of 0xC0-0xCF but DHT, JPG and DAC.
_JPEG_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Markers without a length field (TEM, RSTn, SOI, EOI).
_JPEG_STANDALONE = {0x01, *range(0xD0, 0xDA)}


@dataclass(frozen=True)
class ImageHeader:
    """What an image header declares.

    Attributes:
        format: ``png`` or ``jpeg``.
        width, height: pixels.
        bit_depth: bits per sample (PNG 1, 2, 4, 8 or 16; JPEG 8 or 12).
        channels: samples per pixel as decoded unchanged (1 grey, 2 grey + alpha, 3 colour, 4 colour + alpha).
    """

    format: str
    width: int
    height: int
    bit_depth: int
    channels: int


def read_image_header(path: str | Path) -> ImageHeader | None:
    """The header of a PNG or JPEG file; None for another format (then only a decoder can tell).

    Raises:
        DatasetError: the file is missing or unreadable, or a PNG or JPEG whose header is cut or malformed.
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            head = f.read(33)
            if head[:8] == PNG_SIGNATURE:
                return _png(head, path)
            if head[:2] == b"\xff\xd8":
                f.seek(2)
                return _jpeg(f, path)
    except FileNotFoundError:
        raise DatasetError("image not found", file=path) from None
    except IsADirectoryError:
        raise DatasetError("is a directory, expected an image", file=path) from None
    except OSError as e:
        raise DatasetError(f"cannot read: {e.strerror}", file=path) from None
    return None


def _png(head: bytes, path: Path) -> ImageHeader:
    if len(head) < 29 or head[12:16] != b"IHDR":
        raise DatasetError("PNG header cut or malformed (expected an IHDR chunk first)", file=path)
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    bit_depth, colour = head[24], head[25]
    if colour not in _PNG_CHANNELS or width == 0 or height == 0:
        raise DatasetError(f"PNG header malformed (size {width}x{height}, colour type {colour})", file=path)
    return ImageHeader("png", width, height, bit_depth, _PNG_CHANNELS[colour])


def _jpeg(f, path: Path) -> ImageHeader:
    """Walk the marker segments up to the start of frame (APPn, EXIF and tables come first)."""
    while f.read(1) == b"\xff":
        byte = f.read(1)
        while byte == b"\xff":  # fill bytes
            byte = f.read(1)
        if not byte:
            break
        marker = byte[0]
        if marker in _JPEG_STANDALONE:
            if marker == 0xD9:
                break
            continue
        length = f.read(2)
        if len(length) < 2:
            break
        size = int.from_bytes(length, "big")
        if marker in _JPEG_SOF:
            frame = f.read(6)
            if len(frame) < 6:
                break
            height, width = int.from_bytes(frame[1:3], "big"), int.from_bytes(frame[3:5], "big")
            if width == 0 or height == 0:
                break
            return ImageHeader("jpeg", width, height, frame[0], frame[5])
        if marker == 0xDA or size < 2:  # scan data before any frame header, or a bad length
            break
        f.seek(size - 2, 1)
    raise DatasetError("JPEG header cut or malformed (no start-of-frame segment)", file=path)
