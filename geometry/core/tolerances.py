"""Named tolerances, in one place, with what each one means.

Lengths are in millimetres unless the name says otherwise.
"""

#: Faces whose area is below this fraction of the mean face area count as degenerate.
DEGENERATE_FACE_REL_AREA = 1e-12

#: Relative change of total energy below which a local-global solve stops.
SOLVER_REL_ENERGY_TOL = 1e-10

#: A conformal area scale ratio (max/min over tiles) above this needs a split (paper sec. 4.5).
MAX_SCALE_FACTOR = 2.0

#: Flattening (BFF): eigenvalues of the boundary Schur complement below this fraction of the
#: largest are treated as its null space (the constants) when forming the pseudo-inverse.
FLATTEN_SCHUR_NULL_REL = 1e-12

#: Flattening (BFF): the boundary length-closing step may shrink an edge to no less than this
#: fraction of its target length; a smaller result means the curve cannot close sensibly.
FLATTEN_MIN_CLOSED_LENGTH_REL = 0.05

#: Lift-point stand-in check: a basin holding at least this share of the total gap potential
#: energy counts as heavy (geometry.lift.geometric_deploy_check).
LIFT_SHARE_MIN = 0.05

#: Lift-point stand-in check: a heavy peak must be joined to a lift point by a ridge at least
#: this fraction of its own energy (geometry.lift.geometric_deploy_check).
LIFT_SUPPORT_MIN = 0.5

#: Flat layout: max |edge length K2D - K3D| over tile sides and diagonals that meets the target.
FLAT_EDGE_ERROR_TOL_MM = 1e-3

#: Flat layout: total footprint overlap area (mm^2) counted as zero; also the separating-axis
#: depth (mm) above which two tiles count as overlapping while optimizing.
FLAT_OVERLAP_TOL_MM2 = 1e-6

#: Flat layout: gap opening angles may exceed their bounds by at most this (deg).
FLAT_GAP_ANGLE_TOL_DEG = 0.01

#: Hinges: max distance between paired hinge vertices (before merging) that meets the target.
HINGE_GAP_TOL_MM = 1e-3

#: Flat tiles: 3D interpenetration volume (mm^3) counted as zero.
FLAT_INTERPENETRATION_TOL_MM3 = 1e-6

#: Target loading: vertices closer than this fraction of the bounding-box diagonal are merged
#: (STL stores every triangle corner separately; other exports may split seams).
COINCIDENT_VERTEX_REL_DIST = 1e-7

#: Simulation (geometry.simulate): a route gap counts as closed when the paired side-face
#: midpoints are at most this fraction of the mean tile side apart.
SIM_GAP_CLOSED_REL = 0.01

#: Simulation: deployed when every tile is within this fraction of the mean tile side of the
#: assembled tiles after one rigid alignment (1 %).
SIM_DEVIATION_REL = 0.01

#: Simulation: largest allowed (conservative) overlap depth between neighbouring tiles, as a
#: fraction of the mean tile side.
SIM_PENETRATION_REL = 0.01

#: Simulation: rigid tile edges must stay within this fraction of the mean tile side of their
#: rest length in every step.
SIM_EDGE_LENGTH_REL = 0.005

#: Simulation: the run may stop once no vertex moves more than this fraction of the mean tile
#: side in a step (after the string is fully reeled in).
SIM_SETTLE_REL = 1e-4

#: Rigidity check (geometry.rigidity): singular values below this fraction of the largest one
#: span the null space of the rigidity matrix.
RIGIDITY_SVD_REL = 1e-9

#: CAD tiles: a face whose vertices lie within this distance (mm) of its best-fit plane is built
#: as given; beyond it the vertices are snapped to the intersection of their faces' planes.
CAD_PLANAR_EXACT_MM = 1e-9

#: CAD tiles: a face deviating from planarity by more than this (mm) is rejected (InputError).
CAD_MAX_FACE_DEVIATION_MM = 1e-3

#: CAD checks: two measured openings (string channel or magnet pocket) whose centres lie within
#: this distance (mm) in the assembled pose count as meeting.
CAD_OPENING_MATCH_MM = 1e-4

#: Target planarity of every T3D face, relative to the bounding-box diagonal.
ASSEMBLED_PLANARITY_REL = 1e-6

#: Relative energy change at which the assembled-stage local-global solves stop; the exact
#: planarity polish that follows each solve removes what is left of the planarity residual.
ASSEMBLED_SOLVER_REL_TOL = 1e-6

#: Hinge layout: least distance (mm) kept between flat tiles away from a shared hinge point (a
#: hinged pair may touch only at the hinge and along the corner edge under/over it).  Also
#: bounds how far merging a hinge pair may move a vertex without reaching another tile.
HINGE_LAYOUT_CLEARANCE_MM = 0.1

#: Hinge layout: constraint violation (mm; angle bounds in rad times the mean tile side) at
#: which the rigid layout counts as converged (below HINGE_LAYOUT_TOUCH_MM, so still valid).
HINGE_LAYOUT_FEASIBLE_MM = 1e-6

#: Hinge layout: separation (mm) aimed at where a hinged pair may touch (the hinge vertex and
#: the corner of the other face at the hinge); any positive value keeps the tiles apart, this
#: one absorbs the solver's residual violation.  (Letting that corner cross by a few
#: micrometres closed some hinges further, but the printed rigid tiles then overlapped there.)
HINGE_LAYOUT_TOUCH_MM = 1e-5

#: Hinge layout: gap angle bounds are aimed at this much (deg) inside [theta_min, 90] so that
#: merging hinge pairs (which turns tile sides slightly) keeps them within bounds.
HINGE_ANGLE_MARGIN_DEG = 0.02

#: Hinge trims: the recorded overlap polyhedron is grown by a cube of this half-side (mm) so
#: that subtracting it leaves no numerical sliver of interpenetration.  The overlap of a pair
#: that touches along a vertical edge can be a needle 0.008 x 0.05 x 6 mm (saddle, 200 tiles):
#: grown by 1 um, its cut at a hinge-pad corner failed silently in OCCT; grown by 10 um it cuts.
HINGE_TRIM_GROW_MM = 0.01

#: Simulation: after locking, the run stops as stuck once no vertex moved more than this
#: fraction of the mean tile side in five consecutive steps (a slow creep towards the assembled
#: state is not stuck).
SIM_STILL_REL = 1e-6

#: Simulation: relative shrink of the largest tile deviation over ``stall_checks`` checks that
#: still counts as progress; less means stuck.
SIM_STALL_PROGRESS = 0.02

#: Flat layout solver: gap-angle bounds count as met when violated by at most this (deg); well
#: inside FLAT_GAP_ANGLE_TOL_DEG so the verified angles meet their bounds.
FLAT_SOLVER_ANGLE_TOL_DEG = 1e-4

#: Flat layout: smallest interior angle (rad) at any gap junction (keeps gaps from inverting).
FLAT_ORIENTATION_MIN_RAD = 1e-3

#: Flat layout: clearance between two tiles found overlapping, relative to the mean tile side.
FLAT_SEPARATION_MARGIN_REL = 1e-3

#: CAD interference check: triangle meshes of the solids deviate from the exact surfaces by at
#: most this chordal distance (mm, absolute) ...
CAD_INTERFERENCE_DEFLECTION_MM = 0.02

#: CAD interference check: ... and by at most this angle (rad) between neighbouring triangles
#: along a curved face.
CAD_INTERFERENCE_ANGLE_RAD = 0.5

#: Tiles printed together (``fdm-dual``) count as closer than the print clearance only this
#: far (mm) inside it: their near faces are planar (meshed exactly), the meshes are float32.
PRINT_GAP_TOL_MM = 0.005

#: Largest share of a hinge part's volume that may lie inside a tile in the print pose.
#: Tessellating the curved pin walls a TPU pad shares with its tile gives about 0.05 %
#: (0.007 mm^3 on the 200-tile saddle); a plywood rubber strip on bottoms of slightly different
#: heights sinks about 0.1 % into them; an uncut TPU pin hole puts about 40 % of the pad inside.
CAD_PAD_INTERFERENCE_REL = 0.02

#: The flat layout keeps each slit end's opening this far inside the openings at which its two
#: tiles clear each other (``flat.pose.free_openings``), so the rigid hinge layout, which asks
#: ``HINGE_LAYOUT_CLEARANCE_MM`` along its tilted separating planes, finds them apart already.
FLAT_FREE_MARGIN_DEG = 0.3

#: Mean distance of the assembled top faces from the target (over their whole area), as a
#: fraction of the mean tile side, above which the design is flagged (a quality target).
SURFACE_MEAN_REL = 0.02
#: Largest distance of a point of an assembled top face from the target, as a fraction of the
#: target's bounding-box diagonal, above which the design is flagged (the report marks both):
#: 1.6 mm on a 160 mm part.
SURFACE_MAX_REL = 0.01
#: Largest capstan factor of the string's channels in the assembled pose (the pull force over
#: the force that reaches the far end, ``exp(mu * bend)``) before a warning: a firm hand pull of
#: about 100 N then leaves about 0.1 N to close the last gaps.  A bound of 100 would flag seven
#: of the ten CLI-default designs (dome 185, wave 193, cloud 202, three-shell 603, hemisphere
#: 735, face scan 1.2e3, peanut 4.0e3; the saddle 14), which deploy in the simulation (it has
#: no friction): a warning on most designs tells a user nothing.  At 200 tiles and 200 mm the
#: seven-part three-shell is at 2.1e4.
CAPSTAN_FACTOR_WARN = 1000.0
