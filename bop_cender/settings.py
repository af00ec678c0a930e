"""``--set path.to.field=value``: one setting applied to a tree of frozen dataclass configs, at any depth.

The path is walked through the nested dataclasses (``poses.candidates.n``, ``poses.refine.nelder_mead.maxfev``,
``known_counts``), the value parsed as the field's type, and the tree rebuilt with :func:`dataclasses.replace`
from the leaf up, so that every level's ``__post_init__`` checks the new value. A name that was renamed or removed
is refused with one message that gives the new name or where the removed option's figures are.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from typing import TypeVar

from bop_cender.errors import ConfigError

Config = TypeVar("Config")


def apply_setting(
    config: Config,
    item: str,
    renamed: Mapping[str, str] | None = None,
    removed: Mapping[str, str] | None = None,
    also: Mapping[str, str] | None = None,
) -> Config:
    """``config`` with the setting ``item`` (``path=value``) applied.

    Args:
        config: a frozen dataclass whose fields may be dataclasses in turn.
        item: ``path=value``; the path names a leaf field by its dotted field names.
        renamed: old path -> new path: an old path is refused, naming the new one.
        removed: removed path -> why it was removed (and where its figures are).
        also: old path -> what else the old setting set (appended to its rename message).

    Raises:
        ConfigError: no ``=``, an old or removed name, an unknown path or a section, or a value that is not of the
            field's type or that the config's checks refuse.
    """
    key, sep, text = item.partition("=")
    key = key.strip()
    if not sep:
        raise ConfigError(f"expected section.field=value, got {item!r}", field="--set")
    if renamed and key in renamed:
        more = f"; {also[key]}" if also and key in also else ""
        raise ConfigError(
            f"{key} was renamed {renamed[key]} (--set {renamed[key]}={text.strip()}){more}", field="--set"
        )
    if removed and key in removed:
        raise ConfigError(f"{key} was removed: {removed[key]}", field="--set")
    parts = key.split(".")
    chain = [config]  # the configs along the path, the root first
    for part in parts[:-1]:
        value = getattr(chain[-1], part, None) if _has_field(chain[-1], part) else None
        if not is_dataclass(value):
            raise ConfigError(f"unknown setting {key!r}; known: {', '.join(setting_names(config))}", field="--set")
        chain.append(value)
    target, name = chain[-1], parts[-1]
    if not _has_field(target, name):
        raise ConfigError(f"unknown setting {key!r}; known: {', '.join(setting_names(config))}", field="--set")
    if is_dataclass(getattr(target, name)):
        leaves = [n for n in setting_names(config) if n.startswith(key + ".")]
        raise ConfigError(f"{key} is a section; set one of its fields: {', '.join(leaves)}", field="--set")
    updated = replace(target, **{name: _parse(text.strip(), *_field_kind(target, name), key)})
    for parent, part in zip(reversed(chain[:-1]), reversed(parts[:-1]), strict=True):
        updated = replace(parent, **{part: updated})
    return updated


def setting_names(config: object, prefix: str = "") -> list[str]:
    """Every leaf setting of ``config`` as its dotted path (``poses.candidates.n``), in field order."""
    names = []
    for f in fields(config):
        value = getattr(config, f.name)
        path = prefix + f.name
        names += setting_names(value, path + ".") if is_dataclass(value) else [path]
    return names


def _has_field(config: object, name: str) -> bool:
    return is_dataclass(config) and name in {f.name for f in fields(config)}


def _field_kind(target: object, name: str) -> tuple[type, bool]:
    """The value type of dataclass field ``name`` of ``target`` and whether it may be None (``float | None``)."""
    hint = typing.get_type_hints(type(target))[name]
    args = typing.get_args(hint)
    if type(None) in args:
        (kind,) = [a for a in args if a is not type(None)]
        return kind, True
    return hint if isinstance(hint, type) else type(getattr(target, name)), False


def _parse(text: str, kind: type, optional: bool, key: str) -> object:
    if optional and text.lower() == "none":
        return None
    try:
        if kind is bool:
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(text)
            return text.lower() in ("true", "1", "yes")
        value = kind(text)
    except ValueError:
        expected = f"a {kind.__name__}" + (" or none" if optional else "")
        raise ConfigError(f"{key}: expected {expected}, got {text!r}", field="--set") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{key}: expected a finite number, got {text!r}", field="--set")
    return value
