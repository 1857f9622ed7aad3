"""The design options as the studio offers them: described from :class:`DesignOptions` itself,
read from JSON and checked by the same code as the command line.

:func:`option_specs` lists every field of :class:`DesignOptions` with its type, default and
choices (and, given the command line's ``design`` parser, its flag and help), so that an option
added to :class:`DesignOptions` appears in the page without the page changing.
:func:`parse_options` turns the JSON a client sends into :class:`DesignOptions` keyword
arguments; a value of the wrong type is refused as the command line refuses it, a value out of
range by :meth:`DesignOptions.validate`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any, Literal

from drawstring.fabrication.profiles import (
    BED_MARGIN_MM,
    ESTIMATE_AREA_FACTOR,
    SHIPPED_PROFILES,
    Profile,
    rough_estimate,
)
from drawstring.geometry.core.errors import InputError
from drawstring.pipeline.record import DesignOptions

Kind = Literal["int", "float", "bool", "str"]

#: Options the page shows first (those that exist); the others go under "more options".
MAIN_OPTIONS = ("profile", "printer", "size_mm", "tiles", "hinges", "fit", "cad", "simulate")

#: Options whose ``None`` means "the profile's", and the profile's attribute that says it.
PROFILE_DEFAULTS = {
    "tiles": "default_tiles",
    "size_mm": "default_size_mm",
    "thickness_mm": "thickness_mm",
    "min_gap_angle_deg": "min_gap_angle_deg",
}

#: Not a :class:`DesignOptions` field, but an option of ``drawstring design`` that changes a
#: job's exit status (4 for any warning).
STRICT = "strict"


@dataclass(frozen=True)
class OptionSpec:
    """One option as the API describes it (``GET /api/options``).

    ``count`` is 0 for a single value, else the length of the list it takes; ``optional``
    says whether ``null`` is allowed (it means the profile's default where ``profile_default``
    names the profile's key).
    """

    name: str
    flag: str
    kind: Kind
    count: int
    optional: bool
    default: Any
    choices: tuple[Any, ...] | None
    profile_default: str | None
    help: str
    main: bool

    def to_json(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["choices"] = list(self.choices) if self.choices is not None else None
        data["default"] = list(self.default) if isinstance(self.default, tuple) else self.default
        return data


def _kind(hint: Any) -> tuple[Kind, int, bool, tuple[Any, ...] | None]:
    """(kind, count, optional, choices) of a :class:`DesignOptions` field's type."""
    optional = False
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        optional = len(args) < len(typing.get_args(hint))
        hint = args[0] if len(args) == 1 else str
        origin = typing.get_origin(hint)
    if origin is Literal:
        literals = typing.get_args(hint)
        kind: Kind = "int" if all(isinstance(c, int) for c in literals) else "str"
        return kind, 0, optional, tuple(literals)
    if origin is tuple:
        inner, _, _, choices = _kind(typing.get_args(hint)[0])
        return inner, len(typing.get_args(hint)), optional, choices
    names: dict[Any, Kind] = {bool: "bool", int: "int", float: "float"}
    return names.get(hint, "str"), 0, optional, None


def _cli_actions(parser: argparse.ArgumentParser | None) -> dict[str, argparse.Action]:
    """The ``design`` parser's actions by destination."""
    if parser is None:
        return {}
    return {action.dest: action for action in parser._actions if action.option_strings}


def option_specs(
    design_parser: argparse.ArgumentParser | None = None, profiles: tuple[str, ...] = ()
) -> list[OptionSpec]:
    """Every option of a design, in :class:`DesignOptions`' order, then ``strict``.

    ``design_parser`` (the command line's ``drawstring design`` parser) gives each option its
    flag, help and any choices the type does not say; ``profiles`` are the profile names to
    offer besides the shipped ones.
    """
    hints = typing.get_type_hints(DesignOptions)
    actions = _cli_actions(design_parser)
    specs = []
    for field in dataclasses.fields(DesignOptions):
        kind, count, optional, choices = _kind(hints[field.name])
        action = actions.get(field.name)
        negated = action is None and f"no_{field.name}" in actions
        if negated:
            action = actions[f"no_{field.name}"]
        flag = (
            max(action.option_strings, key=len)
            if action is not None
            else "--" + field.name.replace("_", "-")
        )
        help_text = (action.help or "") if action is not None else ""
        if negated:  # the field is on; its flag turns it off
            help_text = f"on unless {flag}: without it, {help_text}"
        if choices is None and action is not None and action.choices is not None:
            choices = tuple(action.choices)
        if field.name == "profile":
            choices = (*SHIPPED_PROFILES, *profiles)
        default = field.default if field.default is not dataclasses.MISSING else None
        if field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        specs.append(
            OptionSpec(
                name=field.name,
                flag=flag,
                kind=kind,
                count=count,
                optional=optional,
                default=default,
                choices=choices,
                profile_default=PROFILE_DEFAULTS.get(field.name),
                help=help_text.replace("%%", "%"),
                main=field.name in MAIN_OPTIONS,
            )
        )
    strict = actions.get(STRICT)
    specs.append(
        OptionSpec(
            name=STRICT,
            flag="--strict",
            kind="bool",
            count=0,
            optional=False,
            default=False,
            choices=None,
            profile_default=None,
            help=(strict.help or "") if strict is not None else "",
            main=False,
        )
    )
    return specs


def _value(spec: OptionSpec, value: Any) -> Any:
    """One JSON value checked against its option's kind, or InputError worded as argparse's."""
    what = {"int": "a whole number", "float": "a number", "bool": "true or false", "str": "text"}
    if spec.kind == "bool":
        ok = isinstance(value, bool)
    elif spec.kind == "int":
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif spec.kind == "float":
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok and not math.isfinite(value):
            ok = False
    else:
        ok = isinstance(value, str)
    if not ok:
        raise InputError(f"argument {spec.flag}: invalid {spec.kind} value: {value!r}, not "
                         f"{what[spec.kind]}")  # fmt: skip
    if spec.choices is not None and value not in spec.choices:
        listed = ", ".join(repr(c) for c in spec.choices)
        raise InputError(f"argument {spec.flag}: invalid choice: {value!r} (choose from {listed})")
    return float(value) if spec.kind == "float" else value


def parse_options(data: Any, specs: list[OptionSpec]) -> tuple[dict[str, Any], bool]:
    """:class:`DesignOptions` keyword arguments (JSON values, lists for tuples) from a client's
    JSON object, and ``strict``; checked by :meth:`DesignOptions.validate`.

    Raises
    ------
    InputError
        An unknown option, a value of the wrong type or count, or what ``validate`` refuses.
    """
    if not isinstance(data, dict):
        raise InputError("options must be a JSON object of option names and values")
    by_name = {spec.name: spec for spec in specs}
    unknown = sorted(set(data) - set(by_name))
    if unknown:
        raise InputError(
            f"unknown option{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
            f"the options are {', '.join(by_name)}"
        )
    values: dict[str, Any] = {}
    for name, value in data.items():
        spec = by_name[name]
        if value is None:
            if not spec.optional:
                raise InputError(f"argument {spec.flag}: a value is needed (got null)")
            values[name] = None
        elif spec.count:
            if not isinstance(value, list) or len(value) != spec.count:
                raise InputError(
                    f"argument {spec.flag}: expected {spec.count} values as a list (got {value!r})"
                )
            values[name] = [_value(dataclasses.replace(spec, choices=None), v) for v in value]
        else:
            values[name] = _value(spec, value)
    strict = bool(values.pop(STRICT, False))
    design_options(values).validate()
    return values, strict


def design_options(values: dict[str, Any]) -> DesignOptions:
    """:class:`DesignOptions` from :func:`parse_options`' keyword arguments."""
    return DesignOptions(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def estimate(options: DesignOptions, profile: Profile) -> dict[str, Any]:
    """The rough mass, material cost, machine time and beds of a design before it is made
    (``drawstring profiles``' estimate for these options)."""
    size = options.size_mm if options.size_mm is not None else profile.default_size_mm
    if options.grid is not None:
        tiles = options.grid[0] * options.grid[1]
    else:
        tiles = options.tiles if options.tiles is not None else profile.default_tiles
    result: dict[str, Any] = {
        "profile": profile.name,
        "size_mm": size,
        "tiles": tiles,
        "size_range_mm": [profile.size_min_mm, profile.size_max_mm],
        "in_range": profile.size_min_mm <= size <= profile.size_max_mm,
        "currency": profile.currency,
    }
    if not result["in_range"]:
        # the estimate's model (tile thickness, panels, hinge parts) only holds in range
        result["note"] = (
            f"not estimated: {size:g} mm is outside this profile's range "
            f"({profile.size_min_mm:g} to {profile.size_max_mm:g} mm)"
        )
        return result
    guess = rough_estimate(profile, size, tiles)
    result.update(
        mass_g=round(guess.mass_g, 1),
        cost=round(guess.cost, 2),
        hours=round(guess.hours, 2),
        basis=guess.basis,
        beds=_beds(profile, size),
    )
    return result


def _beds(profile: Profile, size_mm: float) -> dict[str, Any]:
    """The least number of beds (or sheets) the tiles' own area takes: a lower bound, as the
    flat layout's gaps and the nesting take more room."""
    room = max(profile.bed_x_mm - 2 * BED_MARGIN_MM, 1.0) * max(
        profile.bed_y_mm - 2 * BED_MARGIN_MM, 1.0
    )
    area = ESTIMATE_AREA_FACTOR * size_mm**2
    what = "print beds" if profile.print_rate_mm3_s > 0 else "sheets"
    return {
        "at_least": max(1, math.ceil(area / room)),
        "of": what,
        "bed_mm": [profile.bed_x_mm, profile.bed_y_mm],
    }
