"""Solvers shared by the stages: the projective local-global solver and its constraint groups,
least squares under inequality rows, and repeated sparse SPD factorizations.
"""

from drawstring.geometry.solve.constrained_lsq import constrained_least_squares
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.planarity import planarize_quads
from drawstring.geometry.solve.solver import LocalGlobalSolver, SolverResult
from drawstring.geometry.solve.spd import SpdSolver

__all__ = [
    "ConstraintGroup",
    "LocalGlobalSolver",
    "SolverResult",
    "SpdSolver",
    "constrained_least_squares",
    "planarize_quads",
]
