"""A checked ``retry with:`` for the refusal of tiles that turn inside out.

When the eq.-1 extrusion turns tiles inside out (or folds a face into a dart,
:class:`~drawstring.geometry.core.errors.ThicknessError`), the pipeline refuses the design.
A suggestion read off the first extrusion would be unchecked: the eq.-1 weights are absolute,
so a larger size is not the same design scaled, and a thinner tile may be too thin for the
profile's string channel.

:func:`checked_retry` repeats the check that refused, and only that (target, flattening,
tiling, eq. 1 and extrusion: 1-6 s each at 200 tiles), for values of ``--size``, ``--thickness``
and ``--tiles`` in turn, and returns the nearest value of one of them that passes, preferring
options the user left at their defaults and never a thickness the profile's string channel
refuses.  It is a bisection: a value it quotes has passed the check, but the values between are
not all known to (the check is not monotonic in general).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from drawstring.fabrication.profiles import MAX_SIZE_MM, MIN_TILES, Profile
from drawstring.geometry.assembled.shape import AssembledResult, optimize_assembled
from drawstring.geometry.core.errors import InputError, ThicknessError
from drawstring.geometry.flatten.conformal import flatten
from drawstring.geometry.target.surface import load_target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.pipeline.cad_stage import ChannelShortfall, boundary_channel_shortfall

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


class _Checker:
    """The refused check, for changed options; flattenings are kept per size."""

    def __init__(
        self,
        target: str,
        options: ResolvedOptions,
        budget: int,
        extra: Callable[[object, object], bool] | None = None,
    ) -> None:
        self.target = target
        self.options = options
        self.budget = budget
        self.extra = extra  # (tiling, assembled) -> passes, asked after eq. 1
        self.runs = 0
        self._flat: dict[float, tuple[object, object]] = {}
        self._seen: dict[tuple[float, float, int | None], bool] = {}

    def passes(self, **changes: float | int) -> bool | None:
        """Whether the options with ``changes`` pass (None once the budget is spent)."""
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
                loaded.vertices,  # type: ignore[attr-defined]
                loaded.faces,  # type: ignore[attr-defined]
                flat_map.uv,  # type: ignore[attr-defined]
                tiles=options.tiles,
                grid=options.grid,
                max_scale_factor=split_bound(options),
            )
            shape = optimize_assembled(
                tiling.vertices,
                tiling.quads,
                loaded.vertices,  # type: ignore[attr-defined]
                loaded.faces,  # type: ignore[attr-defined]
                thickness=options.thickness_mm,
                w_planar=options.weights[0],
                w_square=options.weights[1],
                w_surface=options.weights[2],
            )
            ok = True if self.extra is None else bool(self.extra(tiling, shape))
        except (ThicknessError, InputError):
            ok = False
        self._seen[key] = ok
        return ok


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


def checked_retry(
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
    extra: Callable[[object, object], bool] | None = None,
    options_searched: tuple[str, ...] = ("size", "thickness", "tiles"),
) -> tuple[Retry | None, list[str]]:
    """The nearest ``--size``, ``--thickness`` or ``--tiles`` that passes the check the design
    failed, and what was tried (for the refusal's plain words when nothing passes).

    The check is eq. 1 and its extrusion turning no tile inside out, and with ``extra`` that
    predicate on the tiling and the eq.-1 shape too (the boundary channel check)."""
    from drawstring.pipeline.record import MIN_THICKNESS_MM

    start = time.perf_counter()
    checker = _Checker(target, options, RETRY_CHECKS, extra)
    thinnest = MIN_THICKNESS_MM
    if options.cad:
        from drawstring.cad.features import channel_min_thickness_mm

        thinnest = max(thinnest, channel_min_thickness_mm(profile))
    found: list[tuple[bool, float, str, float, str]] = []  # (explicit, change, option, value)
    tried: list[str] = []
    order = [
        (name, explicit)
        for name, explicit in (
            ("size", asked.size_mm is not None),
            ("thickness", asked.thickness_mm is not None),
            ("tiles", asked.tiles is not None or asked.grid is not None),
        )
        if name in options_searched
    ]
    # options left at their defaults first
    for name, explicit in sorted(order, key=lambda o: o[1]):
        if name == "size":
            # within the profile's stated range (fdm-dual: 80-450 mm): a hand at 1400 mm is
            # not what an fdm-dual user asked for
            limit = min(MAX_SIZE_MM, max(profile.size_max_mm, options.size_mm))
            value = None
            if options.size_mm < limit:
                value = _search_up(lambda s: checker.passes(size_mm=s), options.size_mm, limit)
            if value is None:
                tried.append(f"--size up to {limit:g} (the {profile.name} profile's largest)")
                continue
            found.append(
                (explicit, math.log(value / options.size_mm), "size", value, f"--size {value:g}")
            )
        elif name == "thickness":
            if options.thickness_mm <= thinnest:
                tried.append(f"--thickness (the profile's channel needs {thinnest:.2f} mm)")
                continue
            value = _search_down(
                lambda t: checker.passes(thickness_mm=t), options.thickness_mm, thinnest
            )
            if value is None:
                tried.append(f"--thickness down to {_two_digits_up(thinnest):g}")
                continue
            found.append(
                (
                    explicit,
                    math.log(options.thickness_mm / value),
                    "thickness",
                    value,
                    f"--thickness {value:g}",
                )
            )
        elif options.grid is None and options.tiles is not None:
            # not a trivially easy design: at most RETRY_FEWEST_TILES fewer tiles
            fewest = max(MIN_TILES, math.ceil(options.tiles * RETRY_FEWEST_TILES))
            tiles = _search_tiles(lambda n: checker.passes(tiles=n), options.tiles, fewest)
            if tiles is None:
                tried.append(f"--tiles down to {fewest}")
                continue
            found.append(
                (explicit, math.log(options.tiles / tiles), "tiles", tiles, f"--tiles {tiles}")
            )
        if found and not found[-1][0] and found[-1][1] < math.log(1.3):
            break  # a default changed by under 30 %: near enough, spare the other searches
    seconds = time.perf_counter() - start
    log.info("retry search: found %s; none for %s", [f[4] for f in found], tried)
    if not found:
        return None, tried
    explicit, _, option, value, text = min(found, key=lambda f: (f[0], f[1]))
    # a complete set: the user's own --size, --thickness and --tiles kept beside the change
    kept = [
        f"--{flag} {given:g}"
        for name, flag, given in (
            ("size", "size", asked.size_mm),
            ("thickness", "thickness", asked.thickness_mm),
            ("tiles", "tiles", asked.tiles),
        )
        if given is not None and name != option
    ]
    if asked.grid is not None and option != "tiles":
        kept.append(f"--grid {asked.grid[0]} {asked.grid[1]}")
    text = " ".join([*kept, text])
    return Retry(option, value, text, checker.runs, seconds), tried


def channel_fits(profile: Profile) -> Callable[[Any, Any], bool]:
    """The boundary channel check as a retry search's predicate on (tiling, eq.-1 shape)."""

    def fits(tiling: Any, shape: Any) -> bool:
        boundary = tiling.linkage.boundary_tile
        return boundary_channel_shortfall(profile, shape.tiles, boundary) is None

    return fits


def channel_check(profile: Profile) -> Callable[[Tiling, AssembledResult], None]:
    """The boundary channel check on the first tiling's eq.-1 tiles, raising
    :class:`~drawstring.pipeline.cad_stage.ChannelShortfall` (for ``shape_and_layout``'s
    ``check_first``)."""

    def check(tiling: Tiling, shape: AssembledResult) -> None:
        short = boundary_channel_shortfall(profile, shape.tiles, tiling.linkage.boundary_tile)
        if short is not None:
            have, need = short
            raise ChannelShortfall(
                f"boundary tiles' side faces as narrow as {have:.2f} mm where the string must "
                f"run, and the string channel needs {need:.2f} mm with its walls",
                have,
                need,
            )

    return check


def checked_size_refusal(
    exc: ThicknessError,
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
) -> InputError:
    """The one-line refusal of tiles that turn inside out or fold, ending in a ``retry with:``
    whose options passed this same check (and with CAD the boundary channel check, which
    comes next), or saying in plain words that no size, thickness or tile count tried keeps
    the tiles whole."""
    extra = channel_fits(profile) if options.cad else None
    retry, tried = checked_retry(target, asked, options, profile, extra=extra)
    what = (
        f"--size {options.size_mm:g} mm is too small for {exc.thickness:g} mm thick tiles: "
        f"{exc.inverted} tile(s) turn inside out or fold where this target curves tightly"
    )
    if retry is None:
        return InputError(
            f"{what}, and no {', '.join(tried)} keeps every tile whole: the shape has parts "
            "that curve tighter than tiles this thick can follow (thin fingers, horns or a "
            "nearly closed opening); design a flatter or cut-down part of it"
        )
    log.info("retry search: %s passed after %d checks", retry.text, retry.checks)
    return InputError(f"{what}; retry with: {retry.text}")


def checked_channel_refusal(
    exc: ChannelShortfall,
    target: str,
    asked: DesignOptions,
    options: ResolvedOptions,
    profile: Profile,
) -> InputError:
    """The one-line refusal of boundary tiles too small for the string channel (found on the
    eq.-1 tiles), ending in a ``retry with:`` whose --size or --tiles passed the same
    check."""
    retry, tried = checked_retry(
        target, asked, options, profile, extra=channel_fits(profile),
        options_searched=("size", "tiles"),
    )  # fmt: skip
    count = (
        f"--grid {options.grid[0]} {options.grid[1]}" if options.grid else f"{options.tiles} tiles"
    )
    what = (
        f"--size {options.size_mm:g} mm with {count} gives tiles too small for the "
        f"{profile.name} profile: {exc}"
    )
    if retry is None:
        return InputError(
            f"{what}, and no {', '.join(tried)} gives every boundary tile room for it: parts "
            "of this shape are too narrow for the profile's string channel"
        )
    return InputError(f"{what}; retry with: {retry.text}")
