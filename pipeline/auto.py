"""Values the tool chooses itself where the user gave none of ``--size``, ``--thickness`` and
``--tiles`` (nor ``--grid``).

At the profile's defaults a design can be refused by the one refusing check
(:func:`~.shapes.refusing_shape`: tiles that turn inside out, with CAD tiles too small for the
profile's features), be laid out with its flat tiles missing the profile's fabrication
tolerance (flat edge error or hinge gap over ``tolerance_mm``, with the hinges
:func:`~.run.hinges_chosen` picks), which ends in exit status 3, or with CAD be laid out and
routed with tiles too small for the profile's features (:func:`routed_and_checked`), which
the CAD stage would refuse.  Where the user left all three at their defaults,
:func:`chosen_layout` instead designs with values it finds itself (for a missed tolerance only
with the co-optimization on: without it the fix is to turn it on):

1. refused: the value the refusal's retry search finds (:func:`~.retry.refusal_search`, the
   ``retry with:`` the refusal would quote); a layout that missed the tolerance: the tile
   count one :data:`~.retry.STEP_RATIO` step below the profile's; one too small for a
   feature: the tile count that scales the shortfall away (:func:`~.retry.feature_ratio`);
2. lays the design out with it (with CAD routed and checked), and keeps it where its layout
   meets the tolerance with room for the features;
3. otherwise steps the same option on (each step checked by the refusing check,
   :func:`~.retry.stepped_value`; where tiles too small for a feature have no fewer tiles
   left, the size grows at the tile count reached; where a size misses for hinged tiles that
   overlap where their channels run (:class:`~.cad_stage.WeldedHinges`, which a larger size
   may keep), the tile count steps down at that size) and tries again, at most
   :data:`CHOSEN_LAYOUTS` layouts in all.

Where none meets the tolerance, the defaults' own layout is kept where there was one, else
the most accurate layout tried (exit status 3 either way, its problems listed), never one too
small for the features (where every layout is, the design is refused in words); where no
value passed the refusing check, the refusal stands as it is.  Everything is in the order
above, so the choice is deterministic.  ``metrics.chosen_values`` records why, what was tried
and what was used, ``options`` the values used, and a note says so.  A user who gives any of
the three gets the refusal with its ``retry with:`` instead (for laid-out tiles too small for
the features, :func:`checked_feature_refusal`): their values are never changed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TypeAlias

from drawstring.fabrication.profiles import Profile
from drawstring.geometry.core.errors import DesignError, InputError, ThicknessError
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.target.surface import Target
from drawstring.pipeline.cad_stage import (
    MORE_ROOM,
    FeatureShortfall,
    WeldedHinges,
    tiles_too_small,
)
from drawstring.pipeline.layout_stage import ShapedLayout
from drawstring.pipeline.record import DesignOptions, Progress, ResolvedOptions, rounded
from drawstring.pipeline.retry import (
    Searched,
    complete_retry,
    feature_ratio,
    refusal_checker,
    refusal_search,
    stepped_value,
)
from drawstring.pipeline.routed import Routed, routed_layout, routed_shortfall

#: Layouts the tool makes with values of its own, at most (each takes as long as the
#: defaults' layout).
CHOSEN_LAYOUTS = 3
#: Layouts a refusal of laid-out tiles too small for the profile's features makes to check
#: the value its ``retry with:`` quotes (each takes as long as the layout refused).
RETRY_LAYOUTS = 2

#: option -> the ResolvedOptions field it sets
_FIELDS = {"size": "size_mm", "thickness": "thickness_mm", "tiles": "tiles"}


@dataclass(frozen=True)
class LaidOut:
    """A design laid out at some options: its target and flattening (at that size), the notes
    on them, the layout with the hinges chosen, the options (hinges as chosen) and
    ``metrics.hinge_choice``; with CAD its lift points and route and, where the laid-out
    tiles are too small for the profile's features, the worst shortfall
    (:func:`routed_and_checked`)."""

    loaded: Target
    flat_map: Flattening
    notes: tuple[str, ...]
    shaped: ShapedLayout
    options: ResolvedOptions
    hinge_choice: dict[str, Any] | None
    routed: Routed | None = None
    shortfall: FeatureShortfall | None = None


def routed_and_checked(laid: LaidOut, profile: Profile, progress: Progress) -> LaidOut:
    """With CAD, ``laid`` with its lift points and string route
    (:func:`~.routed.routed_layout`) and the CAD stage's feature checks on them
    (:func:`~.routed.routed_shortfall`), before any solid; without CAD ``laid`` as it is."""
    if not laid.options.cad:
        return laid
    routed = routed_layout(laid.shaped, laid.options, profile, progress)
    return replace(laid, routed=routed, shortfall=routed_shortfall(profile, laid.shaped, routed))


#: What the refusing check raises.
Refused: TypeAlias = ThicknessError | FeatureShortfall
#: Lays the design out at the options given; raises what the refusing check raises.
LayOut = Callable[[ResolvedOptions], LaidOut]
#: The one-line refusal of what the refusing check raised, with the retry search made.
Refuse = Callable[[Refused, Searched], InputError]


def chooses_values(asked: DesignOptions) -> bool:
    """Whether the tool may choose the size, thickness and tile count itself: the user gave
    none of them (nor a grid)."""
    return (
        asked.size_mm is None
        and asked.thickness_mm is None
        and asked.tiles is None
        and asked.grid is None
    )


def _flag(option: str, value: float) -> str:
    return f"--{option} {value:g}"


def _next_value(
    checker: Any, option: str, value: float, profile: Profile, missed: LaidOut | None
) -> float | None:
    """The value of ``option`` to lay out after ``value``, whose layout ``missed`` (None: it
    was refused): a :data:`~.retry.STEP_RATIO` step on, or past tiles too small for the
    profile's features the step :func:`~.retry.feature_ratio` gives (a thinner tile gives
    them no room: no value), checked by the refusing check (:func:`~.retry.stepped_value`)."""
    short = None if missed is None else missed.shortfall
    if short is None:
        return stepped_value(checker, option, value, profile)
    if option == "thickness":
        return None
    return stepped_value(checker, option, value, profile, feature_ratio(option, short))


def chosen_layout(
    first: LaidOut | Refused,
    source: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    lay_out: LayOut,
    refuse: Refuse,
) -> tuple[LaidOut, dict[str, Any] | None]:
    """The layout to design with, and ``metrics.chosen_values`` (None where the defaults'
    layout ``first`` meets the tolerance, or misses it with ``--no-co-optimize``, and with CAD
    has room for the profile's features).  ``first``: the layout at the defaults
    ``options``, or what refused it; ``lay_out``: a layout at other options (with CAD routed
    and checked, :func:`routed_and_checked`); ``refuse``: the refusal raised where no value
    passes the refusing check.  A layout whose tiles are too small for the profile's features
    is a miss, never kept; where every layout made is one, the design is refused in words."""
    tolerance = profile.tolerance_mm
    defaults = {field: getattr(options, field) for field in _FIELDS.values()}
    checker = refusal_checker(options, source, profile)
    option = "tiles"
    record: dict[str, Any] = {"defaults": defaults}
    candidate: float | None
    searched: Searched | None = None
    if isinstance(first, LaidOut):
        accuracy = first.shaped.accuracy_mm
        if first.shortfall is not None:
            why = f"the laid-out tiles were too small for the profile's features: {first.shortfall}"
            record.update(reason="features", shortfall=str(first.shortfall))
        elif accuracy <= tolerance or not options.co_optimize:
            # without the co-optimization no tile count meets it: the fix is to drop
            # --no-co-optimize, which the design's problem line says
            return first, None
        else:
            why = (
                f"the flat tiles missed their hinges by {accuracy:.2g} mm, over the profile's "
                f"fabrication tolerance {tolerance:g} mm"
            )
            record.update(reason="tolerance", accuracy_mm=rounded(accuracy, 9))
        assert options.tiles is not None  # no --grid: chooses_values
        candidate = _next_value(checker, option, options.tiles, profile, first)
        if candidate is None and first.shortfall is not None:
            option = "size"  # no fewer tiles within the bound: the size grows
            candidate = _next_value(checker, option, options.size_mm, profile, first)
    else:
        searched = refusal_search(first, source, asked, options, profile, checker)
        refusal = refuse(first, searched)
        retry = searched[0]
        if retry is None:
            raise refusal
        why = f"the design was refused ({refusal})"
        record.update(reason="refused", refusal=str(refusal))
        option, candidate = retry.option, retry.value
    tried: list[dict[str, Any]] = []
    best: LaidOut | None = None
    carried: dict[str, Any] = {}  # a value kept from an earlier step, by option
    for made in range(1, CHOSEN_LAYOUTS + 1):
        if candidate is None:
            break
        value = int(candidate) if option == "tiles" else candidate
        entry: dict[str, Any] = {"option": option, "value": value}
        if carried:
            entry["with"] = dict(carried)
        tried.append(entry)
        laid: LaidOut | None = None
        try:
            laid = lay_out(replace(options, **_used(entry)))
        except (InputError, DesignError) as exc:  # refused, or no route on its tiles
            entry["refused"] = str(exc)
        else:
            accuracy = laid.shaped.accuracy_mm
            entry.update(accuracy_mm=rounded(accuracy, 9), hinges=str(laid.options.hinges))
            if laid.shortfall is not None:
                entry["shortfall"] = str(laid.shortfall)
            elif accuracy <= tolerance:
                return _chosen(laid, record, tried, why, tolerance)
            elif best is None or accuracy < best.shaped.accuracy_mm:
                best = laid
        if made == CHOSEN_LAYOUTS:
            break  # no layout left to make with a next value
        welded = laid is not None and isinstance(laid.shortfall, WeldedHinges)
        if welded and option == "size" and "tiles" not in carried:  # fewer tiles, this size
            option, carried = "tiles", {"size": value}
            checker = refusal_checker(replace(options, size_mm=value), source, profile)
            assert options.tiles is not None  # no --grid: chooses_values
            candidate = _next_value(checker, option, options.tiles, profile, laid)
            continue
        candidate = _next_value(checker, option, value, profile, laid)
        if candidate is None and option == "tiles" and laid is not None and laid.shortfall:
            # no fewer tiles within the bound: the size grows, at this tile count
            option, carried = "size", {"tiles": value}
            checker = refusal_checker(replace(options, tiles=value), source, profile)
            candidate = _next_value(checker, option, options.size_mm, profile, laid)
    record["tried"] = tried
    kept = first if isinstance(first, LaidOut) and first.shortfall is None else best
    if kept is None:
        if isinstance(first, LaidOut) or any("shortfall" in entry for entry in tried):
            raise InputError(_short_words(first, options, profile, tried))
        assert searched is not None
        raise refuse(first, searched)
    return _kept(kept, record, tried, why, tolerance, defaults_kept=kept is first)


def _short_words(
    first: LaidOut | Refused,
    options: ResolvedOptions,
    profile: Profile,
    tried: list[dict[str, Any]],
) -> str:
    """The one-line refusal where the defaults (``first``, laid out at ``options`` or
    refused) and every value ``tried`` gave no layout with room for the profile's
    features."""
    if isinstance(first, LaidOut):
        assert first.shortfall is not None
        start = tiles_too_small(options, profile, first.shortfall)
    else:
        start = f"at the {profile.name} profile's defaults the design is refused ({first})"
    tried_words = _tried_words(tried) or "no other value passed the first tiling's checks"
    return (
        f"{start}; the values chosen in its place were laid out too: {tried_words}, none with "
        f"tiles that have room for the profile's features; {MORE_ROOM}"
    )


def checked_feature_refusal(
    laid: LaidOut,
    source: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    lay_out: LayOut,
) -> InputError:
    """The one-line refusal of laid-out tiles too small for the profile's features
    (``laid.shortfall``) at the options the user gave, right after the layout and the route:
    ending in a ``retry with:`` whose value was laid out, routed and passed the same checks
    (at most :data:`RETRY_LAYOUTS` layouts, stepped as :func:`chosen_layout` steps), or saying
    in words what to change.  The option changed is one the user left at its default where
    there is one (the tile count first, then the size), else their tile count.  ``options``:
    the options as resolved, which the layouts start from (``laid.options`` has the hinges
    chosen for it)."""
    short = laid.shortfall
    assert short is not None
    tiles_given = asked.tiles is not None or asked.grid is not None
    size_first = options.grid is not None or (tiles_given and asked.size_mm is None)
    option = "size" if size_first else "tiles"
    value: float = options.size_mm if option == "size" else int(options.tiles or 0)
    checker = refusal_checker(options, source, profile)
    what = tiles_too_small(options, profile, short)
    tried: list[dict[str, Any]] = []
    candidate = _next_value(checker, option, value, profile, laid)
    for made in range(1, RETRY_LAYOUTS + 1):
        if candidate is None:
            break
        value = int(candidate) if option == "tiles" else candidate
        entry: dict[str, Any] = {"option": option, "value": value}
        tried.append(entry)
        again: LaidOut | None = None
        try:
            again = lay_out(replace(options, **{_FIELDS[option]: value}))
        except (InputError, DesignError) as exc:  # refused, or no route on its tiles
            entry["refused"] = str(exc)
        else:
            entry.update(accuracy_mm=again.shaped.accuracy_mm, hinges=str(again.options.hinges))
            if again.shortfall is None:
                retry = complete_retry(asked, option, _flag(option, value))
                return InputError(f"{what}; retry with: {retry}")
            entry["shortfall"] = str(again.shortfall)
        if made == RETRY_LAYOUTS:
            break  # no layout left to make with a next value
        candidate = _next_value(checker, option, value, profile, again)
    checked = ""
    for entry in tried:
        at = complete_retry(asked, option, _flag(option, entry["value"]))
        if "shortfall" in entry:
            checked += f" (laid out at {at}, the tiles still fall short: {entry['shortfall']})"
        else:
            checked += f" (at {at} the design is refused)"
    return InputError(f"{what}; {MORE_ROOM}{checked}")


def _used(entry: dict[str, Any]) -> dict[str, Any]:
    """The ResolvedOptions fields a ``tried`` entry changes, with their values."""
    changes = {**entry.get("with", {}), entry["option"]: entry["value"]}
    return {_FIELDS[option]: value for option, value in changes.items()}


def _flags(entry: dict[str, Any]) -> str:
    """The options a ``tried`` entry changes, as the user types them."""
    changes = {**entry.get("with", {}), entry["option"]: entry["value"]}
    return " ".join(_flag(option, value) for option, value in changes.items())


def _tried_words(tried: list[dict[str, Any]]) -> str:
    words = []
    for entry in tried:
        flag = _flags(entry)
        if "refused" in entry:
            words.append(f"{flag} (refused)")
        elif "shortfall" in entry:
            words.append(f"{flag} ({entry['shortfall']})")
        else:
            words.append(f"{flag} ({entry['accuracy_mm']:.2g} mm, {entry['hinges']} hinges)")
    return ", ".join(words)


def _chosen(
    laid: LaidOut,
    record: dict[str, Any],
    tried: list[dict[str, Any]],
    why: str,
    tolerance: float,
) -> tuple[LaidOut, dict[str, Any]]:
    """``laid``, which meets the tolerance, with its note, and ``metrics.chosen_values``."""
    last = tried[-1]
    record.update(tried=tried, used=_used(last))
    misses = tried[:-1]
    short = any("shortfall" in entry for entry in misses)
    missed = "missed" if short else f"missed the {tolerance:g} mm"
    before = f"; {_tried_words(misses)} {missed}" if misses else ""
    room = "tiles have room for the profile's features and whose " if laid.routed else ""
    note = (
        f"chosen values: you gave none of --size, --thickness, --tiles, and at the defaults "
        f"{why}{before}; the design uses {_flags(last)}, whose "
        f"{room}flat tiles meet their hinges within {last['accuracy_mm']:.2g} mm (give any of "
        "the three to have your own values, and a refusal with its retry where they do not "
        "work)"
    )
    return replace(laid, notes=(*laid.notes, note)), record


def _kept(
    laid: LaidOut,
    record: dict[str, Any],
    tried: list[dict[str, Any]],
    why: str,
    tolerance: float,
    *,
    defaults_kept: bool,
) -> tuple[LaidOut, dict[str, Any]]:
    """``laid``, the defaults' layout or the most accurate one tried, none meeting the
    tolerance, with its note, and ``metrics.chosen_values``."""
    tried_words = _tried_words(tried) or "no other value passed the refusing check"
    short = any("shortfall" in entry for entry in tried)
    room = " with room for the profile's features" if short else ""
    if defaults_kept:
        record["used"] = {}
        kept = "the defaults are kept"
    else:
        entry = min(
            (e for e in tried if "accuracy_mm" in e and "shortfall" not in e),
            key=lambda e: float(e["accuracy_mm"]),
        )
        record["used"] = _used(entry)
        kept = f"the design uses the most accurate, {_flags(entry)}"
    note = (
        f"chosen values: you gave none of --size, --thickness, --tiles, and at the defaults "
        f"{why}; tried {tried_words}, none within {tolerance:g} mm{room}, so {kept}"
    )
    return replace(laid, notes=(*laid.notes, note)), record
