"""Closed-loop simulator and the virtual conveyor.

Set points → drive controller replica → conveyor plant (:mod:`engine`,
compiled kernels in the private :mod:`_kernel`), and on top of it the virtual conveyor
(:mod:`virtual`: realism a drive scope adds, faults) and time series over
simulated days (:mod:`fleet`). The hot path of output-error fitting; kernels
are compiled with numba and cached on disk after the first run.
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.simulate.engine import (
        SimulationResult,
        elastic_substeps,
        simulate,
    )
    from chaintwin.simulate.faults import (
        Fault,
        FaultType,
        fault_names,
        parse_fault,
        parse_faults,
        register_fault,
    )
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

_LAZY: dict[str, str] = {
    "DEFAULT_BELT_STIFFNESS_N_M": "chaintwin.simulate.plant",
    "Fault": "chaintwin.simulate.faults",
    "FaultType": "chaintwin.simulate.faults",
    "GenerateSummary": "chaintwin.simulate.fleet",
    "PlantParameters": "chaintwin.simulate.plant",
    "Realism": "chaintwin.simulate.virtual",
    "Setpoints": "chaintwin.simulate.setpoints",
    "SimulationResult": "chaintwin.simulate.engine",
    "VirtualRun": "chaintwin.simulate.virtual",
    "default_setpoints": "chaintwin.simulate.virtual",
    "elastic_substeps": "chaintwin.simulate.engine",
    "fault_names": "chaintwin.simulate.faults",
    "faulty_plant": "chaintwin.simulate.virtual",
    "from_arrays": "chaintwin.simulate.setpoints",
    "generate": "chaintwin.simulate.fleet",
    "integrate_speed": "chaintwin.simulate.setpoints",
    "parse_fault": "chaintwin.simulate.faults",
    "parse_faults": "chaintwin.simulate.faults",
    "ramp": "chaintwin.simulate.setpoints",
    "register_fault": "chaintwin.simulate.faults",
    "run_virtual": "chaintwin.simulate.virtual",
    "simulate": "chaintwin.simulate.engine",
    "stairs": "chaintwin.simulate.setpoints",
    "trapezoid": "chaintwin.simulate.setpoints",
    "trapezoid2": "chaintwin.simulate.setpoints",
}
"""Module of each public name (imported on first use, PEP 562)."""

__all__ = [
    "DEFAULT_BELT_STIFFNESS_N_M",
    "Fault",
    "FaultType",
    "GenerateSummary",
    "PlantParameters",
    "Realism",
    "Setpoints",
    "SimulationResult",
    "VirtualRun",
    "default_setpoints",
    "elastic_substeps",
    "fault_names",
    "faulty_plant",
    "from_arrays",
    "generate",
    "integrate_speed",
    "parse_fault",
    "parse_faults",
    "ramp",
    "register_fault",
    "run_virtual",
    "simulate",
    "stairs",
    "trapezoid",
    "trapezoid2",
]


__getattr__ = lazy_getattr(__name__, _LAZY)
