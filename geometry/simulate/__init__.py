"""The deployment simulation: the pull from the flat layout to the assembled shape (paper
section 5.4).
"""

from drawstring.geometry.simulate.deploy import simulate_deployment, simulate_stage
from drawstring.geometry.simulate.result import SimulationResult

__all__ = [
    "SimulationResult",
    "simulate_deployment",
    "simulate_stage",
]
