"""Calibrating a conveyor: the rigid model's parameters from recordings with known loads.

:func:`calibrate` (:mod:`chaintwin.calibrating.procedure`) fits the model
(:mod:`chaintwin.identify`) and checks the result by weighing the calibration
runs with it (:mod:`chaintwin.weigh`), so it sits above both;
:mod:`chaintwin.calibrating.methods` compares the identification methods
(``chaintwin identify --method ls|rls|oe``). The names below are imported on
first use (PEP 562).
"""

import typing as _typing

from chaintwin._lazy import lazy_getattr

if _typing.TYPE_CHECKING:
    from chaintwin.calibrating.procedure import calibrate

_LAZY: dict[str, str] = {"calibrate": "chaintwin.calibrating.procedure"}

__all__ = ["calibrate"]


__getattr__ = lazy_getattr(__name__, _LAZY)
