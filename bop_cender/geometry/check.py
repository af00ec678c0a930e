"""Shape checks at public tensor entries (kornia's ``KORNIA_CHECK_SHAPE`` habit): a wrong shape is one
clear ``ValueError`` naming the argument, not an index error deep inside a batched kernel.

``check_shape(x, "B V 4 4", "T_cam_model")``: each space-separated token is a fixed size (an integer)
or a name; a name binds on first use and must agree wherever it appears again in the same ``sizes``
mapping, so several arguments can be checked against each other (``B`` of the poses equals ``B`` of
the weights). ``*`` matches any one dimension.
"""

from __future__ import annotations

from collections.abc import MutableMapping
from typing import Any


def check_shape(x: Any, spec: str, name: str, sizes: MutableMapping[str, int] | None = None) -> dict[str, int]:
    """Check that ``x.shape`` matches ``spec``; return (and fill) the named sizes.

    Raises:
        ValueError: wrong number of dimensions, a fixed size that differs, or a named size that
            disagrees with an earlier binding.
    """
    sizes = {} if sizes is None else sizes
    shape = tuple(int(d) for d in getattr(x, "shape", ()))
    tokens = spec.split()
    if len(shape) != len(tokens):
        raise ValueError(f"{name}: expected shape ({', '.join(tokens)}), got {shape}")
    for token, size in zip(tokens, shape, strict=True):
        if token == "*":
            continue
        if token.isdigit():
            if size != int(token):
                raise ValueError(f"{name}: expected shape ({', '.join(tokens)}), got {shape}")
        elif token in sizes and sizes[token] != size:
            raise ValueError(f"{name}: expected {token} = {sizes[token]} (from an earlier argument), got shape {shape}")
        else:
            sizes[token] = size
    return dict(sizes)
