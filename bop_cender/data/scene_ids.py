"""The one reversible mapping between scene folder names (strings) and BOP's int scene ids.

BOP result CSVs need an int ``scene_id``. Plain folders map to their number
(``000123`` -> 123); DIMO's synthetic variant folders map to ``scene * 100 + variant``
(``000123_17`` -> 12317). The writer, the reader, ``score`` and the toolkit adapter all call
these two functions, and nothing else knows the rule.
"""

from __future__ import annotations

import re

_PLAIN = re.compile(r"^\d+$")
_SUFFIXED = re.compile(r"^(\d+)_(\d{2})$")

#: Variant suffixes run 00..99, so they fit in the last two decimal digits.
VARIANT_BASE = 100


def scene_folder_to_int(scene_id: str) -> int:
    """``'000123'`` -> 123, ``'000123_17'`` -> 12317.

    Raises:
        ValueError: the name is neither ``digits`` nor ``digits_dd``.
    """
    m = _SUFFIXED.match(scene_id)
    if m:
        return int(m.group(1)) * VARIANT_BASE + int(m.group(2))
    if _PLAIN.match(scene_id):
        return int(scene_id)
    raise ValueError(f"scene id {scene_id!r} is neither 'NNNNNN' nor 'NNNNNN_VV'")


def int_to_scene_folder(value: int, suffixed: bool) -> str:
    """Inverse of :func:`scene_folder_to_int`; ``suffixed`` says which kind of folder the split has."""
    if value < 0:
        raise ValueError(f"scene id must be non-negative, got {value}")
    if suffixed:
        scene, variant = divmod(value, VARIANT_BASE)
        return f"{scene:06d}_{variant:02d}"
    return f"{value:06d}"


def is_suffixed(scene_id: str) -> bool:
    """Whether a folder name carries a DIMO variant suffix (``000123_17``)."""
    return bool(_SUFFIXED.match(scene_id))
