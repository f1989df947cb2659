"""Compiled (numba) kernels of the closed-loop conveyor simulator.

Internal: :mod:`chaintwin.simulate.engine` packs a
:class:`~chaintwin.simulate.plant.PlantParameters` into a coefficient vector
(layout ``C_*`` below) and calls these kernels; outputs are rows ``O_*`` of
a ``(N_OUT, n)`` array, one column per controller cycle.

One controller cycle ``k`` (time ``t_k = k·dt``)
-----------------------------------------------
1. Sample speed ω_k and angle θ_k; position P + speed PI with clamping
   anti-windup gives the torque set point u_k (``controller``).
2. The motor torque follows ``1/(1 + sτ)`` driven by the set point of the
   *previous* cycle, u_{k-1} (one cycle of delay), solved exactly over the
   cycle: ``T_{k+1} = T_k + (1 - e^{-dt/τ})·(u_{k-1} - T_k)``; the plant
   sees the exact mean torque over the cycle (over each sub-step when
   sub-stepping).
3. The plant advances one cycle (rigid: one step; elastic: ``n_sub``
   semi-implicit Euler sub-steps).

Power-flow cases (which efficiency applies)
-------------------------------------------
Rigid model: with ``f = F·r/i`` (belt resistance at the motor, ideal gear),
``M = m·r²/i²`` and ``A`` the motor torque net of motor/gear losses, the
gear carries ``Q = f + M·α`` (ideal). Motoring (power motor → belt,
``Q·ω > 0``) the motor supplies ``Q/η`` so ``(J_d + M/η)·α = A − f/η``;
generating (belt drives motor) it supplies ``Q·η`` so
``(J_d + M·η)·α = A − f·η``. Solving both, ``Q`` has the sign of
``f·J_d + M·A`` in either case, so that sign decides the case without
iteration (``rigid_core``). Elastic model: the spring force ``F_k`` at the
sprocket rim is the gear's output load; motoring while ``F_k·ω ≥ 0``
(torque ``F_k·ρ/(i·η)``), else generating (``F_k·ρ·η/i``).

Coulomb friction at standstill
------------------------------
A speed that would cross zero within a step, or that decays below a tiny
band (1e-6 rad/s), is set to exactly zero ("stuck"). While stuck, the drive
torque must exceed the breakaway level (static friction, with the efficiency
of the power flow that motion would have) in one direction to move;
otherwise the speed stays at zero. This holds the belt without chattering
while the drive holds position.

The plain rigid model
---------------------
The identification model (rigid, no realism switch, no fault) runs in
:func:`plain_kernel`, a lean twin of :func:`rigid_kernel`: it takes its belt
terms precomputed from the coefficients (``M_RED0`` …, computed in Python
by :func:`belt_terms` once per run) and is compiled without floating-point
contraction (``_EXACT``), fused multiply-adds written out (:func:`fma`), so
that its numbers do not depend on how LLVM fuses operations.

Coefficient layout
------------------
:data:`COEFFICIENTS` is the one table of the coefficient vector: name,
meaning and unit of each entry, in order. The index constants ``C_*`` are
made from it (one :func:`_coef` call per row) and :func:`pack` builds a
vector from values given by name, checking that every entry is given once.

Modules: :mod:`.layout` (the coefficient and output layouts, plain
Python), :mod:`.pieces` (compiled pieces the kernels share), :mod:`.rigid`
(:func:`rigid_kernel`, :func:`plain_kernel`) and :mod:`.elastic`
(:func:`elastic_kernel`). numba's on-disk cache is stamped with the file of
the cached function only, while a kernel compiles in the pieces and freezes
the ``C_*`` constants; each kernel module therefore calls
:func:`~.layout.keep_cache_fresh` first, which invalidates its cache when a
file it depends on changed.
"""

from __future__ import annotations

from chaintwin.simulate._kernel.elastic import elastic_kernel
from chaintwin.simulate._kernel.layout import (
    COEFFICIENTS,
    N_COEF,
    N_OUT,
    O_BELT_POSITION,
    O_BELT_SPEED,
    O_FORCE,
    O_LOAD,
    O_LOSS,
    O_POSITION,
    O_SPEED,
    O_TORQUE,
    O_TORQUE_SP,
    pack,
)
from chaintwin.simulate._kernel.pieces import belt_terms
from chaintwin.simulate._kernel.rigid import plain_extra, plain_kernel, plain_step, rigid_kernel

__all__ = [
    "COEFFICIENTS",
    "N_COEF",
    "N_OUT",
    "O_BELT_POSITION",
    "O_BELT_SPEED",
    "O_FORCE",
    "O_LOAD",
    "O_LOSS",
    "O_POSITION",
    "O_SPEED",
    "O_TORQUE",
    "O_TORQUE_SP",
    "belt_terms",
    "elastic_kernel",
    "pack",
    "plain_extra",
    "plain_kernel",
    "plain_step",
    "rigid_kernel",
]
