"""The variants of a sweep: comma lists of design options, their product, and the names.

Each list option (:data:`~.command.LIST_OPTIONS`) maps to the :class:`DesignOptions` field of
the same destination as the ``drawstring design`` option; its values are converted to that
field's type.
A list option whose field this drawstring's designs do not have is refused with its name.
"""

from __future__ import annotations

import itertools
import math
import re
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from drawstring.geometry.core.errors import InputError
from drawstring.pipeline.record import DesignOptions


@dataclass(frozen=True)
class ListOption:
    """One list option as given: its flag, its :class:`DesignOptions` field, its values."""

    flag: str
    field: str
    values: tuple[str, ...]
    #: the values the option allows (``--hinges``: dual, top), or None for any
    choices: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Variant:
    """One design of the sweep: its folder's name, its options, and the list values it takes
    (``(flag, value)`` for every list option given)."""

    name: str
    options: DesignOptions
    values: tuple[tuple[str, str], ...]


def split_values(flag: str, text: str) -> tuple[str, ...]:
    """The values of a comma list, in order, each once."""
    items = [item.strip() for item in text.split(",")]
    if any(not item for item in items):
        raise InputError(
            f"{flag} takes values separated by commas, none empty (got {text!r}), e.g. {flag} 40,80"
        )
    return tuple(dict.fromkeys(items))


def checked(lists: Sequence[ListOption]) -> None:
    """Refuse a list option whose field :class:`DesignOptions` does not have, and values
    outside an option's choices."""
    known = {f.name for f in fields(DesignOptions)}
    for option in lists:
        if option.field not in known:
            raise InputError(
                f"{option.flag} is not an option of this drawstring's designs (drawstring "
                f"design has no {option.flag}); leave it out of the sweep"
            )
        if option.choices is not None:
            for value in option.values:
                if value not in option.choices:
                    allowed = ", ".join(option.choices)
                    raise InputError(
                        f"{option.flag} values must be among {allowed} (got {value!r})"
                    )


def variants(base: DesignOptions, lists: Sequence[ListOption], target: str) -> list[Variant]:
    """Every combination of the list options' values (the product, the first option varying
    slowest), each named by the values that vary (``profile-laser-epdm_tiles-40``), or by the
    target where none does."""
    checked(lists)
    hints = typing.get_type_hints(DesignOptions)
    typed = [
        [(value, _typed(option, hints[option.field], value)) for value in option.values]
        for option in lists
    ]
    varying = [len(option.values) > 1 for option in lists]
    out: list[Variant] = []
    seen: dict[str, int] = {}
    for combination in itertools.product(*typed):
        chosen = list(zip(lists, combination, varying, strict=True))
        parts = [f"{o.flag.lstrip('-')}-{_shown(text)}" for o, (text, _), v in chosen if v]
        name = _safe("_".join(parts) or _target_name(target))
        seen[name] = seen.get(name, 0) + 1
        if seen[name] > 1:  # two values that read alike (two my.toml in different folders)
            name = f"{name}-{seen[name]}"
        options = replace(base, **{o.field: value for o, (_, value), _ in chosen})
        out.append(Variant(name, options, tuple((o.flag, text) for o, (text, _), _ in chosen)))
    return out


def _typed(option: ListOption, hint: Any, text: str) -> Any:
    """``text`` as a value of the field's type: int, float, or (str, a Literal) as it is."""
    kinds = typing.get_args(hint) if _is_union(hint) else (hint,)
    kinds = tuple(k for k in kinds if k is not type(None))
    kind = kinds[0] if len(kinds) == 1 else str
    if kind is int:
        try:
            return int(text)
        except ValueError:
            raise InputError(
                f"{option.flag} takes whole numbers separated by commas (got {text!r})"
            ) from None
    if kind is float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise InputError(f"{option.flag} takes numbers separated by commas (got {text!r})")
        return value
    return text


def _is_union(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def _shown(text: str) -> str:
    """A value as a folder name shows it: a file by its stem, a number as written."""
    path = Path(text)
    return path.stem if path.suffix else text


def _target_name(target: str) -> str:
    path = Path(target)
    return path.stem if path.suffix else target.strip().lower()


def _safe(name: str) -> str:
    """A folder name of letters, digits and ``. _ + -``."""
    cleaned = re.sub(r"[^A-Za-z0-9._+-]+", "-", name).strip(".-")
    return cleaned or "variant"
