"""Closed-loop simulator and the virtual conveyor.

Set points → drive controller replica → conveyor plant (:mod:`engine`,
compiled kernels in the private :mod:`_kernel`), and on top of it the virtual conveyor
(:mod:`virtual`: realism a drive scope adds, faults) and time series over
simulated days (:mod:`fleet`). The hot path of output-error fitting; kernels
are compiled with numba and cached on disk after the first run.
"""

from chaintwin.simulate.engine import (
    SimulationResult,
    elastic_substeps,
    simulate,
)
from chaintwin.simulate.faults import FAULT_NAMES, Fault, parse_fault, parse_faults
from chaintwin.simulate.fleet import GenerateSummary, generate
from chaintwin.simulate.plant import DEFAULT_BELT_STIFFNESS_N_M, PlantParameters
from chaintwin.simulate.setpoints import (
    Setpoints,
    from_arrays,
    integrate_speed,
    ramp,
    stairs,
    trapezoid,
    trapezoid2,
)
from chaintwin.simulate.virtual import (
    Realism,
    VirtualRun,
    default_setpoints,
    faulty_plant,
    run_virtual,
)

__all__ = [
    "DEFAULT_BELT_STIFFNESS_N_M",
    "FAULT_NAMES",
    "Fault",
    "GenerateSummary",
    "PlantParameters",
    "Realism",
    "Setpoints",
    "SimulationResult",
    "VirtualRun",
    "default_setpoints",
    "elastic_substeps",
    "faulty_plant",
    "from_arrays",
    "generate",
    "integrate_speed",
    "parse_fault",
    "parse_faults",
    "ramp",
    "run_virtual",
    "simulate",
    "stairs",
    "trapezoid",
    "trapezoid2",
]
