"""Device simulator: a physically consistent model of the seed paper's experiment.

A seated subject traces a rectangle with the right hand while an upper-arm IMU and an
end-effector robot (two forearm cuffs) stream to the service; the shoulder stays put
(proper), then moves with the reach (compensatory). ``simulate`` returns the contract
messages and the ground truth.

    from simulator import SimConfig, simulate
    sim = simulate(SimConfig(seed=1, duration_s=480.0))
    sim.messages, sim.truth, sim.subject
"""

from typing import TYPE_CHECKING, Any

from simulator.config import (
    COMPENSATORY,
    DEFAULT_LAYOUT_480,
    PROPER,
    REST,
    TRANSITION,
    SimConfig,
    default_layout,
)
from simulator.subject import Subject, draw_subject
from simulator.truth import Cycles, Truth

if TYPE_CHECKING:
    from simulator.session import Simulation, simulate

__all__ = [
    "COMPENSATORY",
    "DEFAULT_LAYOUT_480",
    "PROPER",
    "REST",
    "TRANSITION",
    "Cycles",
    "SimConfig",
    "Simulation",
    "Subject",
    "Truth",
    "default_layout",
    "draw_subject",
    "simulate",
]


def __getattr__(name: str) -> Any:
    # the simulation itself (and SciPy with it) loads on first use: `rehab analyze` and the
    # service import this package only for its configuration
    if name in ("Simulation", "simulate"):
        from simulator import session

        return getattr(session, name)
    raise AttributeError(f"module 'simulator' has no attribute {name!r}")
