"""Files of the output folder, one writer per file group.

Each writer takes the :class:`~drawstring.pipeline.run.Design` and the (staging) folder,
writes its files and returns their paths relative to the folder.  Output is deterministic: fixed
float formatting, no timestamps in files.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.route.result import route_to_json
from drawstring.geometry.tiling.linkage import gap_centroids
from drawstring.output import pictures
from drawstring.output.fit_picture import save_fit
from drawstring.output.flat_picture import save_flat
from drawstring.output.lift_picture import save_lift
from drawstring.pipeline.cad_stage import route_lengths
from drawstring.pipeline.fit_quality import surface_distances
from drawstring.pipeline.layout_stage import fabricated_tiles
from drawstring.pipeline.record import Design, Writer


def format_obj(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64] | list[list[int]],
    header: str = "",
    groups: list[tuple[str, int, int]] | None = None,
) -> str:
    """Wavefront OBJ text: ``v`` lines with 6 decimals (mm) and 1-based polygon ``f`` lines.

    ``groups`` optionally names consecutive face ranges ``(name, first_face, end_face)``.
    """
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(vertices, dtype=float)]
    starts = {first: name for name, first, _ in groups or []}
    for k, face in enumerate(faces):
        if k in starts:
            lines.append(f"g {starts[k]}")
        lines.append("f " + " ".join(str(int(i) + 1) for i in face))
    return "\n".join(lines) + "\n"


def write_lifted_mesh(result: Design, folder: Path) -> list[str]:
    """``lifted.obj``: the quad grid lifted onto the target (M3D), before optimization."""
    tiling = result.tiling
    text = format_obj(
        tiling.vertices,
        tiling.quads,
        header="drawstring lifted quad grid M3D (mm); one quad per tile, tile order as design.json",
    )
    (folder / "lifted.obj").write_text(text, encoding="utf-8")
    return ["lifted.obj"]


def write_target_mesh(result: Design, folder: Path) -> list[str]:
    """``target.obj``: the target exactly as the design approximates it (scaled to ``--size``,
    repaired, in the design's frame: the frame of ``assembled.obj``), so the fit can be
    measured in any tool."""
    target = result.target
    text = format_obj(
        target.vertices,
        target.faces,
        header=(
            f"drawstring target {target.name} (mm) as the design approximates it: scaled, in the "
            "frame of assembled.obj; metrics.surface_distance_* measure the tiles' top faces "
            "against it"
        ),
    )
    (folder / "target.obj").write_text(text, encoding="utf-8")
    return ["target.obj"]


def write_pictures(result: Design, folder: Path) -> list[str]:
    """``scale_factor.png`` and ``lifted.png``."""
    pictures.save_scale_factor(result.tiling, folder / "scale_factor.png")
    pictures.save_lifted(result.target, result.tiling, folder / "lifted.png")
    return ["scale_factor.png", "lifted.png"]


def write_tiles(result: Design, folder: Path) -> list[str]:
    """``assembled.obj`` (T3D) and ``flat.obj`` (T2D, fabrication pose), tiles as closed meshes."""
    header = (
        "drawstring {what} (mm): tile t is group tile_t, vertices 8t+1..8t+8 = top BL, BR, TR,"
        " TL, then the bottom corners under them; faces outward"
    )
    for name, tiles, what in (
        ("assembled.obj", result.tiles_assembled, "assembled configuration T3D"),
        ("flat.obj", result.tiles_flat, "flat configuration T2D, top faces up"),
    ):
        (folder / name).write_text(tiles_obj(tiles, header.format(what=what)), encoding="utf-8")
    return ["assembled.obj", "flat.obj"]


def write_tiles_npz(result: Design, folder: Path) -> list[str]:
    """``tiles.npz``: the tiles at full precision (float64, mm), ``assembled`` (T3D) and
    ``fabricated`` (each T3D tile moved rigidly onto its place in the flat layout, the pose the
    deployment simulation starts from), so ``drawstring simulate`` repeats the design's run
    exactly (the OBJ files round to 1e-6 mm); and per tile how far its top face sits from the
    target, ``surface_distance_mean_mm`` (over the face) and ``surface_distance_max_mm``."""
    from drawstring.geometry.core.npz import save_npz

    distances = surface_distances(result.tiles_assembled, result.target)
    save_npz(
        folder / "tiles.npz",
        {
            "assembled": np.asarray(result.tiles_assembled, dtype=np.float64),
            "fabricated": fabricated_tiles(result.hinge_layout, result.tiles_assembled),
            "surface_distance_mean_mm": distances.tile_mean,
            "surface_distance_max_mm": distances.tile_max,
        },
    )
    return ["tiles.npz"]


def tiles_obj(tiles: NDArray[np.float64], header: str) -> str:
    """OBJ text of (T, 8, 3) tiles as closed outward quad meshes, one group per tile."""
    count = len(tiles)
    faces = (TILE_FACES[None, :, :] + 8 * np.arange(count)[:, None, None]).reshape(-1, 4)
    groups = [(f"tile_{t}", 6 * t, 6 * t + 6) for t in range(count)]
    return format_obj(tiles.reshape(-1, 3), faces, header=header, groups=groups)


def write_route(result: Design, folder: Path) -> list[str]:
    """``route.json``: the ordered string route with sides, positions and lift points.

    ``length_flat_mm`` and ``length_assembled_mm`` are the string's length along the channels
    (:func:`~.cad_stage.route_lengths`, as bom.csv and manifest.json state it), not the
    polyline through the gap centroids the route was planned on.
    """

    linkage = result.tiling.linkage
    document = route_to_json(
        result.route,
        linkage,
        gap_centroids(linkage, result.tiles_flat[:, :4, :2]),
        gap_centroids(linkage, result.tiles_assembled[:, :4]),
        result.lift.lift_gaps,
    )
    document["length_flat_mm"], document["length_assembled_mm"] = route_lengths(result)
    text = json.dumps(_rounded(document), indent=1, allow_nan=False)
    (folder / "route.json").write_text(text + "\n", encoding="utf-8")
    return ["route.json"]


def _rounded(value: Any, digits: int = 6) -> Any:
    """JSON-ready copy with floats rounded (numpy values become Python ones)."""
    if isinstance(value, dict):
        return {str(k): _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_rounded(v, digits) for v in value]
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer | int):
        return int(value)
    if isinstance(value, np.floating | float):
        return round(float(value), digits) if np.isfinite(value) else None
    return value


def write_stage_pictures(result: Design, folder: Path) -> list[str]:
    """``assembled.png``, ``flat.png`` (tiles, hinges, gaps, route, lift points), ``lift.png``
    and ``fit.png`` (the assembled tiles coloured by their distance from the target)."""
    pictures.save_assembled(result, folder / "assembled.png")
    save_flat(result, folder / "flat.png")
    save_lift(result, folder / "lift.png")
    save_fit(result, surface_distances(result.tiles_assembled, result.target), folder / "fit.png")
    return ["assembled.png", "flat.png", "lift.png", "fit.png"]


def write_hinges(result: Design, folder: Path) -> list[str]:
    """``hinges.json``: every hinge's tiles, corners, side (top/bottom), OBJ vertex ids in
    ``flat.obj`` and position; the trimmed overlaps for the ``top`` strategy."""
    from drawstring.geometry.hinges.placement import hinge_vertex_json

    document = hinge_vertex_json(result.hinge_layout, result.tiling.linkage)
    text = json.dumps(_rounded(document), indent=1, allow_nan=False)
    (folder / "hinges.json").write_text(text + "\n", encoding="utf-8")
    return ["hinges.json"]


def write_deployment(result: Design, folder: Path) -> list[str]:
    """``deploy.npz`` (frames of tile vertices from flat to assembled) and ``deploy.gif``."""
    if result.simulation is None:
        return []
    return save_deployment(result.simulation, result.route, folder)


def save_deployment(simulation: Any, route: Any, folder: Path) -> list[str]:
    """Write ``deploy.npz`` and ``deploy.gif`` of a simulation whose string follows ``route``
    (a ``Route`` or (S, 4) steps ``(gap, tile, enter_side, leave_side)``)."""
    from drawstring.geometry.simulate.inputs import route_snap_pairs, route_steps
    from drawstring.geometry.simulate.result import save_deploy_npz
    from drawstring.output.deploy_pictures import route_polylines, save_deploy_gif

    save_deploy_npz(simulation, folder / "deploy.npz")
    pairs = route_snap_pairs(route_steps(route))[0]
    frames = simulation.frames
    save_deploy_gif(frames, route_polylines(frames, pairs), folder / "deploy.gif")
    return ["deploy.npz", "deploy.gif"]


def write_fabrication_files(result: Design, folder: Path) -> list[str]:
    """The profile's fabrication files under ``fabrication/`` (only when CAD ran)."""
    if result.cad_flat is None:
        return []
    # the exports load the CAD kernel (seconds), which a --no-cad design never needs
    from drawstring.fabrication.exports import write_fabrication
    from drawstring.output.assembly_guide import write_guide
    from drawstring.pipeline.cad_stage import cad_inputs, print_tiles

    inputs = cad_inputs(result)
    return write_fabrication(
        folder,
        profile=result.profile,
        linkage=result.tiling.linkage,
        tiles_flat=print_tiles(result),
        tiles_assembled=result.tiles_assembled,
        hinge_side=result.hinge_layout.sides,
        route_steps=inputs.route_steps,
        lift_tiles=inputs.lift_tiles,
        magnet_pairs=inputs.magnet_pairs,
        trims=inputs.trims,
        cad_flat=result.cad_flat,
        cad_assembled=result.cad_assembled,
        design_name=result.target.name,
        guide=write_guide,
        printer=result.printer,
        slice_beds=result.options.slice,
    )


DEFAULT_WRITERS: tuple[Writer, ...] = (
    write_target_mesh,
    write_lifted_mesh,
    write_tiles,
    write_tiles_npz,
    write_route,
    write_pictures,
    write_stage_pictures,
    write_hinges,
    write_deployment,
    write_fabrication_files,
)
