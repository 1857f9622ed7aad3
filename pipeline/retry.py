"""A checked ``retry with:`` for the refusal of tiles that turn inside out.

The pipeline refuses a design by one check, asked before any layout
(:func:`~drawstring.pipeline.shapes.refusing_shape`): eq. 1 and its extrusion on the first
tiling turning tiles inside out or folding a face into a dart
(:class:`~drawstring.geometry.core.errors.ThicknessError`), and with CAD boundary tiles too
narrow for the string channel or hinged corners without room for their hinge strips
(:func:`feature_check`).  A suggestion read off the first extrusion would be unchecked:
the eq.-1 weights are absolute, so a larger size is not the same design scaled, and a thinner
tile may be too thin for the profile's string channel.

:func:`checked_retry` asks that same check (target, flattening, tiling, eq. 1 and extrusion:
1-6 s each at 200 tiles) for values of ``--size``, ``--thickness`` and ``--tiles`` in turn,
and of the values that pass it, whether every tile keeps a bottom face of at least
:data:`RETRY_BOTTOM_SHARE` of its top's area (:func:`bottom_share`): the first value that
keeps the tiles whole leaves those under the tightest curvature nearly inside out, and such a
design is written with its flat tiles a millimetre off and does not deploy.  It returns the
nearest value of one option that passes both, preferring options the user left at their
defaults and never a thickness below the string channel's (:func:`thinnest_tile_mm`, with or
without CAD).  Where none does, the refusal says in plain words why the method cannot
serve the shape at this profile.  It is a bisection: a value it quotes has passed, but the
values between are not all known to (the checks are not monotonic in general).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from drawstring.fabrication.profiles import MAX_SIZE_MM, MIN_TILES, Profile
from drawstring.geometry.assembled.frustums import quad_vector_areas
from drawstring.geometry.assembled.shape import AssembledResult
from drawstring.geometry.core.errors import InputError, ThicknessError
from drawstring.geometry.flatten.conformal import Flattening, flatten
from drawstring.geometry.target.surface import Target, load_target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.pipeline.cad_stage import (
    FeatureShortfall,
    boundary_channel_shortfall,
    hinge_strip_shortfall,
    strip_words,
)
from drawstring.pipeline.record import Progress
from drawstring.pipeline.shapes import FirstCheck, ShapeCache, refusing_shape

if TYPE_CHECKING:
    from drawstring.pipeline.record import DesignOptions, ResolvedOptions

log = logging.getLogger(__name__)

#: Check runs one search may make in all (each 1-6 s at 200 tiles).
RETRY_CHECKS = 24
#: The fewest tiles a retry may ask for, as a share of those asked (a 3 x 3 grid deploys
#: anything, and is not the design asked for).
RETRY_FEWEST_TILES = 0.25


@dataclass(frozen=True)
class Retry:
    """A value that passed the check: the option, its value as the user types it, and the
    check runs the search made."""

    option: str
    value: float
    text: str
    checks: int
    seconds: float


def _two_digits_up(value: float) -> float:
    step = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.ceil(value / step - 1e-9) * step


def _two_digits_down(value: float) -> float:
    step = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.floor(value / step + 1e-9) * step


#: The least share of its top face's area every tile's bottom face must keep (projected on
#: the top) for a retry to be offered.  The search stops at the first value that keeps every
#: tile whole, and there the tiles under the tightest curvature have bottoms shrunk to
#: slivers.  Measured on the corpus at fdm-dual's defaults (``--no-cad``): retries whose
#: bottoms kept 2-15 % were written with flat tiles 0.2-8 mm off and did not deploy, goat_head
#: at --size 420 and 450 (40 and 41 %) did not deploy either, while goat_head at --tiles 50
#: (44 %) and ogre_face at --tiles 129 (45 %) deployed with their flat tiles within 0.004 mm.
RETRY_BOTTOM_SHARE = 0.43


def bottom_share(shape: AssembledResult) -> float:
    """The smallest share of its top face's area a tile's bottom face keeps, projected on the
    top (1 on a flat target, 0 where a tile is about to turn inside out)."""
    top = quad_vector_areas(shape.top, shape.quads)
    bottom = quad_vector_areas(shape.bottom, shape.quads)
    share = np.einsum("ki,ki->k", top, bottom) / np.einsum("ki,ki->k", top, top)
    return float(share.min(initial=1.0))


#: What one checked value gave: passed, refused again (inside out, or with CAD the string
#: channel), or whole but with some tile nearly inside out (:data:`RETRY_BOTTOM_SHARE`).
PASSED, REFUSED, NEARLY_FOLDED = "passed", "refused", "nearly folded"


class _Checker:
    """The refusing check (:func:`~.shapes.refusing_shape`, after the grid check) for
    changed options, and on the shapes that pass it :func:`bottom_share`; flattenings are kept
    per size."""

    def __init__(
        self,
        target: str,
        options: ResolvedOptions,
        budget: int,
        check: FirstCheck | None = None,
    ) -> None:
        self.target = target
        self.options = options
        self.budget = budget
        self.check = check  # with CAD, the boundary channel check
        self.runs = 0
        self._flat: dict[float, tuple[Target, Flattening]] = {}
        self._seen: dict[tuple[float, float, int | None], str] = {}

    def passes(self, **changes: float | int) -> bool | None:
        """Whether the options with ``changes`` pass the refusing check and lay out with every
        tile's bottom keeping :data:`RETRY_BOTTOM_SHARE` of its top (None once the budget is
        spent)."""
        outcome = self.outcome(**changes)
        return None if outcome is None else outcome == PASSED

    def outcomes(self) -> set[str]:
        """What the values checked so far gave."""
        return set(self._seen.values())

    def outcome(self, **changes: float | int) -> str | None:
        """:data:`PASSED`, :data:`REFUSED` or :data:`NEARLY_FOLDED` for the options with
        ``changes`` (None once the budget is spent)."""
        from drawstring.pipeline.checks import check_grid, mesh_corners
        from drawstring.pipeline.layout_stage import split_bound

        options = replace(self.options, **changes)
        key = (options.size_mm, options.thickness_mm, options.tiles)
        if key in self._seen:
            return self._seen[key]
        if self.runs >= self.budget:
            return None
        self.runs += 1
        try:
            if options.size_mm not in self._flat:
                loaded = load_target(
                    self.target, size_mm=options.size_mm, resolution=options.resolution,
                    repair=options.repair,
                )  # fmt: skip
                flat_map = flatten(
                    loaded.vertices, loaded.faces, mode="rectangle",
                    corners=mesh_corners(loaded, options),
                )  # fmt: skip
                self._flat[options.size_mm] = (loaded, flat_map)
            loaded, flat_map = self._flat[options.size_mm]
            check_grid(options, flat_map, from_profile=False)
            tiling = tile_surface(
                loaded.vertices, loaded.faces, flat_map.uv, tiles=options.tiles,
                grid=options.grid, max_scale_factor=split_bound(options),
            )  # fmt: skip
            # the pipeline's own refusing check, on the shape it lays out when the close one
            # is not kept
            shape = refusing_shape(
                tiling, loaded, options, Progress(quiet=True), ShapeCache(), self.check
            )
        except (ThicknessError, InputError):
            outcome = REFUSED
        else:
            share = bottom_share(shape)
            outcome = PASSED if share >= RETRY_BOTTOM_SHARE else NEARLY_FOLDED
            log.info("retry check %s: bottom faces keep %.3f of their tops", key, share)
        self._seen[key] = outcome
        return outcome


def _search_up(passes: Callable[[float], bool | None], start: float, limit: float) -> float | None:
    """Smallest two-digit value above ``start`` (which fails) that passes, up to ``limit``."""
    lo, hi = start, None
    step = 1.5
    value = start
    while value < limit:
        value = min(limit, _two_digits_up(value * step))
        ok = passes(value)
        if ok is None:
            return None
        if ok:
            hi = value
            break
        lo = value
    if hi is None:
        return None
    while True:
        mid = _two_digits_up(math.sqrt(lo * hi))
        if mid >= hi or mid <= lo:
            return hi
        ok = passes(mid)
        if ok is None:
            return hi
        lo, hi = (lo, mid) if ok else (mid, hi)


def _search_down(
    passes: Callable[[float], bool | None], start: float, floor: float
) -> float | None:
    """Largest two-digit value below ``start`` (which fails) down to ``floor`` that passes."""
    low = _two_digits_up(floor)
    ok = passes(low)
    if not ok:
        return None
    lo, hi = low, start
    while True:
        mid = _two_digits_down(0.5 * (lo + hi))
        if mid <= lo or mid >= hi:
            return lo
        ok = passes(mid)
        if ok is None:
            return lo
        lo, hi = (mid, hi) if ok else (lo, mid)


def _search_tiles(passes: Callable[[int], bool | None], start: int, fewest: int) -> int | None:
    """Most tiles below ``start`` (which fails) that pass, from ``fewest`` up."""
    if fewest >= start or not passes(fewest):
        return None
    lo, hi = fewest, start
    while hi - lo > max(1, lo // 20):
        mid = (lo + hi) // 2
        ok = passes(mid)
        if ok is None:
            return lo
        lo, hi = (mid, hi) if ok else (lo, mid)
    return lo


def thinnest_tile_mm(profile: Profile) -> float:
    """The thinnest tile a retry may ask for: the profile's string channel at mid-thickness
    with its walls and the hinge recesses and labels sunk above and below it, as
    :func:`~drawstring.cad.features.channel_min_thickness_mm` gives it (the CAD stage refuses
    thinner tiles), here without loading the CAD kernel: a ``--no-cad`` design is the same
    product without its solids, and a tile with no room for its string is not one."""
    from drawstring.pipeline.record import MIN_THICKNESS_MM

    wall = max(profile.nozzle_mm, 2.0 * profile.kerf_mm, 0.3)
    sink = {
        "through-holes": profile.hinge_thickness_mm,
        "dovetail": 2.0 * profile.hinge_thickness_mm,
        "glue-recess": 0.5 * profile.hinge_thickness_mm,
    }.get(profile.hinge_interlock, 0.25 * profile.thickness_mm)
    label = min(max(0.07 * profile.thickness_mm, 0.3), 2.0)
    bore = 0.5 * (profile.string_diameter_mm + profile.channel_clearance_mm)
    return max(MIN_THICKNESS_MM, 2.0 * (bore + wall + max(sink, label)))


def _search_option(
    name: str,
    checker: _Checker,
    options: ResolvedOptions,
    profile: Profile,
    thinnest: float,
    within: float,
) -> tuple[float, str, float, str] | str:
    """The nearest value of option ``name`` (``size``, ``thickness`` or ``tiles``) that
    passes, changing it by a log ratio of at most ``within``: (change, option, value, text),
    or the words for what was tried where none does."""
    bound = math.exp(within)
    if name == "size":
        # within the profile's stated range (fdm-dual: 80-450 mm): a hand at 1400 mm is not
        # what an fdm-dual user asked for
        largest = min(MAX_SIZE_MM, max(profile.size_max_mm, options.size_mm))
        limit = min(largest, _two_digits_down(options.size_mm * min(bound, 1e6)))
        size = None
        if options.size_mm < limit:
            size = _search_up(lambda s: checker.passes(size_mm=s), options.size_mm, limit)
        if size is None:
            return f"--size up to {largest:g} (the {profile.name} profile's largest)"
        return math.log(size / options.size_mm), "size", size, f"--size {size:g}"
    if name == "thickness":
        if options.thickness_mm <= thinnest:
            return f"--thickness (the string channel needs {thinnest:.2f} mm)"
        floor = max(thinnest, options.thickness_mm / bound)
        value = None
        if options.thickness_mm > floor:
            value = _search_down(
                lambda t: checker.passes(thickness_mm=t), options.thickness_mm, floor
            )
        if value is None:
            least = " (the string channel's least)" if floor == thinnest else ""
            return f"--thickness down to {_two_digits_up(floor):g}{least}"
        return math.log(options.thickness_mm / value), "thickness", value, f"--thickness {value:g}"
    assert options.tiles is not None
    # not a trivially easy design: at most RETRY_FEWEST_TILES fewer tiles
    fewest = max(MIN_TILES, math.ceil(options.tiles * RETRY_FEWEST_TILES))
    tiles = _search_tiles(
        lambda n: checker.passes(tiles=n),
        options.tiles,
        max(fewest, math.ceil(options.tiles / bound)),
    )
    if tiles is None:
        return f"--tiles down to {fewest}"
    return math.log(options.tiles / tiles), "tiles", tiles, f"--tiles {tiles}"


#: A value the tool chooses itself after one whose design missed the fabrication tolerance
#: (:mod:`~.auto`) lies this far beyond it: tiles and thickness times it, the size over it.
#: A quarter fewer tiles a step: four steps from the profile's count reach the fewest a retry
#: may ask for (:data:`RETRY_FEWEST_TILES`).  Only the layout is checked, not the
#: deployment: julius_face (corpus) at 160 tiles meets the tolerance with top hinges but does
#: not deploy, at 150 it meets it and deploys.
STEP_RATIO = 0.75
#: Check runs one such step may make.
STEP_CHECKS = 4


#: A value stepped past tiles too small for the profile's features scales the room they have
#: by the worst shortfall and this much more (:func:`feature_ratio`): tiles do not scale
#: exactly with --size or --tiles (their thickness stays, and the tiling and the
#: co-optimization change), so the room a feature has varies by a few percent, and not
#: monotonically.
FEATURE_MARGIN = 1.04


def feature_ratio(option: str, short: FeatureShortfall) -> float:
    """The first step's ratio (as :data:`STEP_RATIO`: tiles times it, the size over it) past
    laid-out tiles too small for a feature by ``short``: the one that scales the room
    ``short.have`` up to ``short.need`` with :data:`FEATURE_MARGIN` (a tile's side goes with
    the size, and with one over the square root of the tile count), but never a larger step
    than :data:`STEP_RATIO`: a hinged corner crowded by a second strip is a matter of the
    tiles' shape, which the tiling changes, more than of their size."""
    scale = short.have / (short.need * FEATURE_MARGIN)
    return max(STEP_RATIO, scale**2 if option == "tiles" else scale)


def stepped_value(
    checker: _Checker, option: str, value: float, profile: Profile, ratio: float = STEP_RATIO
) -> float | None:
    """The next value of ``option`` (``size``, ``thickness`` or ``tiles``) beyond ``value``,
    which gave a design that misses the fabrication tolerance or the profile's features: a
    ``ratio`` step on (:data:`STEP_RATIO`, or :func:`feature_ratio`), and on by
    :data:`STEP_RATIO` steps until one passes ``checker`` (at most :data:`STEP_CHECKS` runs),
    within the retry search's bounds (the profile's largest size, the string channel's
    thinnest tile, a quarter of the tiles); None where none does."""
    base = checker.options
    checker.budget = checker.runs + STEP_CHECKS
    while True:
        if option == "tiles":
            assert base.tiles is not None
            value = math.floor(value * ratio)
            if value < max(MIN_TILES, math.ceil(base.tiles * RETRY_FEWEST_TILES)):
                return None
            ok = checker.passes(tiles=int(value))
        elif option == "size":
            value = _two_digits_up(value / ratio)
            if value > min(MAX_SIZE_MM, max(profile.size_max_mm, base.size_mm)):
                return None
            ok = checker.passes(size_mm=value)
        else:
            value = _two_digits_down(value * ratio)
            if value < thinnest_tile_mm(profile):
                return None
            ok = checker.passes(thickness_mm=value)
        if ok is None:
            return None
        if ok:
            return value
        ratio = STEP_RATIO


def checked_retry(
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    check: FirstCheck | None = None,
    options_searched: tuple[str, ...] = ("size", "thickness", "tiles"),
    checker: _Checker | None = None,
) -> tuple[Retry | None, list[str], set[str]]:
    """The nearest ``--size``, ``--thickness`` or ``--tiles`` that passes the check the design
    failed with no tile nearly inside out (:class:`_Checker`), what was tried (for
    the refusal's plain words when nothing passes) and what the values tried gave
    (:data:`REFUSED`, :data:`NEARLY_FOLDED`).

    The check is :func:`~.shapes.refusing_shape` with ``check`` (with CAD, the boundary
    channel check): the one the pipeline refuses by, so the retry is not refused again.
    ``checker``: the one to ask (it keeps what it found for a later :func:`stepped_value`)."""
    start = time.perf_counter()
    checker = checker or _Checker(target, options, RETRY_CHECKS, check)
    thinnest = thinnest_tile_mm(profile)
    found: list[tuple[bool, float, str, float, str]] = []  # (explicit, change, option, value)
    tried: list[str] = []
    order = [
        (explicit, rank, name)
        for rank, (name, explicit) in enumerate(
            (
                ("tiles", asked.tiles is not None or asked.grid is not None),
                ("thickness", asked.thickness_mm is not None),
                ("size", asked.size_mm is not None),
            )
        )
        if name in options_searched and (name != "tiles" or options.grid is None)
    ]
    # options left at their defaults first, the cheaper checks first (a size needs its own
    # flattening); each search only within the change of the best value found so far
    for explicit, _, name in sorted(order):
        within = min((f[1] for f in found if f[0] == explicit), default=math.inf)
        if any(not f[0] for f in found) and explicit:
            break  # an option left at its default changes: the user's own stay as given
        result = _search_option(name, checker, options, profile, thinnest, within)
        if isinstance(result, str):
            tried.append(result)
            continue
        found.append((explicit, *result))
        if not explicit and result[0] < math.log(1.3):
            break  # a default changed by under 30 %: near enough, spare the other searches
    seconds = time.perf_counter() - start
    log.info(
        "retry search: found %s; none for %s (%d checks, %.1f s)",
        [f[4] for f in found], tried, checker.runs, seconds,
    )  # fmt: skip
    if not found:
        # in the order the options are listed everywhere: --size, --thickness, --tiles
        tried.sort(key=lambda words: ("--size", "--thickness", "--tiles").index(words.split()[0]))
        return None, tried, checker.outcomes()
    explicit, _, option, value, text = min(found, key=lambda f: (f[0], f[1]))
    text = complete_retry(asked, option, text)
    return Retry(option, value, text, checker.runs, seconds), tried, checker.outcomes()


def complete_retry(asked: DesignOptions, option: str, change: str) -> str:
    """A complete set of options for ``retry with:``: the user's own ``--size``,
    ``--thickness``, ``--tiles`` and ``--grid`` kept beside ``change``, the flag and value
    of ``option`` (``size``, ``thickness`` or ``tiles``)."""
    kept = [
        f"--{name} {given:g}"
        for name, given in (
            ("size", asked.size_mm),
            ("thickness", asked.thickness_mm),
            ("tiles", asked.tiles),
        )
        if given is not None and name != option
    ]
    if asked.grid is not None and option != "tiles":
        kept.append(f"--grid {asked.grid[0]} {asked.grid[1]}")
    return " ".join([*kept, change])


def feature_check(profile: Profile, options: ResolvedOptions) -> FirstCheck:
    """The CAD feature checks on the first tiling's eq.-1 tiles, raising
    :class:`~drawstring.pipeline.cad_stage.FeatureShortfall`: boundary tiles with room for
    the string channel (:func:`~.cad_stage.boundary_channel_shortfall`) and hinged corners
    with room for their strips on any face ``options.hinges`` can put them on
    (:func:`~.cad_stage.hinge_strip_shortfall`).  The ``check`` of
    :func:`~.shapes.refusing_shape` with CAD."""

    def check(tiling: Tiling, shape: AssembledResult) -> None:
        short = boundary_channel_shortfall(profile, shape.tiles, tiling.linkage.boundary_tile)
        if short is not None:
            have, need = short
            raise FeatureShortfall(
                f"boundary tiles' side faces as narrow as {have:.2f} mm where the string must "
                f"run, and the string channel needs {need:.2f} mm with its walls",
                have,
                need,
            )
        strips = hinge_strip_shortfall(
            profile, tiling.linkage, shape.tiles, options.min_gap_angle_deg, options.hinges
        )
        if strips is not None:
            raise FeatureShortfall(strip_words(profile, *strips), *strips)

    return check


def _plain_words(tried: list[str], outcomes: set[str]) -> str:
    """Why no option tried gives a design: what ``tried`` lists, and what the values gave."""
    why = (
        "the shape has parts that curve tighter than tiles this thick can follow (thin "
        "fingers, horns or a nearly closed opening)"
    )
    if NEARLY_FOLDED in outcomes:
        why = (
            "where the tiles stay whole some are still nearly inside out (bottom faces under "
            f"{RETRY_BOTTOM_SHARE:.0%} of their tops' area), and such a linkage neither lays "
            f"out flat nor deploys: {why}"
        )
    return f"no {', '.join(tried)} gives a design this method can make: {why}"


#: What a retry search found: the retry (None where nothing passed), the words for what was
#: tried, and what the values tried gave (:func:`checked_retry`).
Searched = tuple[Retry | None, list[str], set[str]]


def refusal_checker(options: ResolvedOptions, target: str, profile: Profile) -> _Checker:
    """The checker a refusal's retry search asks: the refusing check with CAD's feature
    check where the design has CAD (:func:`feature_check`), with room for
    :data:`RETRY_CHECKS` runs."""
    check = feature_check(profile, options) if options.cad else None
    return _Checker(target, options, RETRY_CHECKS, check)


def refusal_search(
    exc: ThicknessError | FeatureShortfall,
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    checker: _Checker | None = None,
) -> Searched:
    """The retry search for the refusal of ``exc``: every option for tiles that turn inside
    out, ``--size`` and ``--tiles`` for tiles too small for the profile's features (a thinner
    tile does not widen them)."""
    checker = checker or refusal_checker(options, target, profile)
    searched = ("size", "tiles") if isinstance(exc, FeatureShortfall) else None
    return checked_retry(
        target, asked, options, profile, checker.check, checker=checker,
        **({} if searched is None else {"options_searched": searched}),
    )  # fmt: skip


def checked_size_refusal(
    exc: ThicknessError,
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    searched: Searched | None = None,
) -> InputError:
    """The one-line refusal of tiles that turn inside out or fold, ending in a ``retry with:``
    whose options passed this same check (and with CAD the boundary channel check, which
    comes next) with no tile nearly inside out, or saying in plain words why no size,
    thickness or tile count tried gives a design.  ``searched``: the search already made
    (:func:`refusal_search`)."""
    retry, tried, outcomes = searched or refusal_search(exc, target, asked, options, profile)
    what = (
        f"--size {options.size_mm:g} mm is too small for {exc.thickness:g} mm thick tiles: "
        f"{exc.inverted} tile(s) turn inside out or fold where this target curves tightly"
    )
    if retry is None:
        return InputError(
            f"{what}, and {_plain_words(tried, outcomes)}; design a flatter or cut-down part of it"
        )
    log.info("retry search: %s passed after %d checks", retry.text, retry.checks)
    return InputError(f"{what}; retry with: {retry.text}")


def checked_channel_refusal(
    exc: FeatureShortfall,
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    searched: Searched | None = None,
) -> InputError:
    """The one-line refusal of tiles too small for the string channel or the hinge strips
    (found on the eq.-1 tiles, :func:`feature_check`), ending in a ``retry with:`` whose
    --size or --tiles passed the same check.  ``searched``: the search already made
    (:func:`refusal_search`)."""
    retry, tried, outcomes = searched or refusal_search(exc, target, asked, options, profile)
    count = (
        f"--grid {options.grid[0]} {options.grid[1]}" if options.grid else f"{options.tiles} tiles"
    )
    what = (
        f"--size {options.size_mm:g} mm with {count} gives tiles too small for the "
        f"{profile.name} profile: {exc}"
    )
    if retry is None:
        if NEARLY_FOLDED in outcomes:
            return InputError(f"{what}, and {_plain_words(tried, outcomes)}")
        return InputError(
            f"{what}, and no {', '.join(tried)} gives the tiles room for it: parts of this "
            "shape are too narrow for the profile's string channel and hinge strips"
        )
    return InputError(f"{what}; retry with: {retry.text}")
