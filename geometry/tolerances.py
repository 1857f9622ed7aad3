"""Named tolerances, in one place, with what each one means.

Lengths are in millimetres unless the name says otherwise.
"""

#: Faces whose area is below this fraction of the mean face area count as degenerate.
DEGENERATE_FACE_REL_AREA = 1e-12

#: Relative change of total energy below which a local-global solve stops.
SOLVER_REL_ENERGY_TOL = 1e-10

#: A conformal area scale ratio (max/min over tiles) above this needs a split (paper sec. 4.5).
MAX_SCALE_FACTOR = 2.0
