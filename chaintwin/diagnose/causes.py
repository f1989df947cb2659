"""Probable causes: which fault a feature's rise points to, most specific first."""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping

from scipy import stats

from chaintwin.simulate.faults import fault_types

from .features import IMPULSIVE, feature_spec, is_tracked
from .impacts import MIN_POOLED_HITS

__all__ = [
    "CAUSE_PRIORITY",
    "EXPLAINING_ORDER",
    "NOTE_CAUSES",
    "cause_priority",
    "explaining_causes",
    "impact_context",
    "one_per_revolution",
    "resolve_causes",
    "shaft_harmonic",
]

CAUSE_PRIORITY: tuple[str, ...] = (
    "obstruction",
    "sprocket",
    "elongation",
    "gear",
    "bearing",
    "lubrication",
    "friction",
    "structure",
)
"""Causes from the most specific to the least: a specific fault also moves
the general features (an obstruction raises the mean friction, an elongated
chain's articulation raises friction, a broken tooth raises the broadband
residual), so those are read as the specific fault when it is present."""

EXPLAINING_ORDER: tuple[str, ...] = ("obstruction", "sprocket", "gear", "elongation", "bearing")
"""Which present cause names a feature that several explain, first first; the
causes of registered faults not listed here come after these, in the fault
table's order."""

NOTE_CAUSES = frozenset({"payload_event", IMPULSIVE})
"""Causes reported on the recording and never alarmed: an item caught for a
while, a tray dropped, is an event of operation, not wear; an impulsive
residual that nothing explains yet names no cause to page anyone about."""

OUTPUT_HARMONICS = 16
"""Harmonics of the output shaft's order an unexplained peak is read as the gear's at."""

ONE_PER_REV_P = 0.05
"""Two-sided significance below which pooled knocks are not one per belt revolution."""


def impact_context(values: Mapping[str, float], exceeded: Collection[str]) -> str:
    """What made a recording's torque impulsive, from its own features.

    Parameters
    ----------
    values : dict of str to float
        The recording's features (``impact_isolated``, ``impact_drags``,
        ``impact_hits_per_rev``, ``impact_pooled_hits``, ``impact_pooled_revs``).
    exceeded : collection of str
        Features this recording exceeded (a worn sprocket's ``sprocket_comb``,
        a tooth's ``comb_<shaft>``).

    Returns
    -------
    str
        ``obstruction`` (knocks at about one per belt revolution, pooled over
        recordings), ``sprocket``, ``gear``, ``payload_event`` (impacts with
        no such rate, or dragging ones) or ``impulsive`` (no impact stands
        out and no line rose: nothing names a cause, a note until something
        does; a bearing's spalls, a tooth whose comb has not risen yet).
    """
    knocks = values.get("impact_isolated") or 0.0
    drags = values.get("impact_drags") or 0.0
    rate = values.get("impact_hits_per_rev", float("nan"))
    pooled = values.get("impact_pooled_hits") or 0.0
    revs = values.get("impact_pooled_revs") or 0.0
    # the cause is read from the knocks as pooled, even those the conveyor's own
    # random knocks could make (which do not raise the rate itself)
    seen = pooled / revs if pooled >= MIN_POOLED_HITS and revs > 0 else rate
    if one_per_revolution(pooled, seen):
        return "obstruction"
    if "sprocket_comb" in exceeded:
        return "sprocket"
    if any(e.startswith("comb_") for e in exceeded):
        return "gear"
    if knocks > 0 or drags > 0 or rate > 0:
        return "payload_event"
    return IMPULSIVE


def one_per_revolution(hits: float, rate: float) -> bool:
    """Whether pooled knocks are consistent with one hit per belt revolution.

    ``hits`` knocks over ``hits / rate`` revolutions: a Poisson count whose
    mean would be the revolutions for an obstacle fixed to the rail. Consistent
    when neither tail probability is below :data:`ONE_PER_REV_P` / 2 (two knocks
    over 4.6 revolutions are: p = 0.17 below). Needs at least
    :data:`~chaintwin.diagnose.impacts.MIN_POOLED_HITS` knocks (the rate is 0
    with fewer).
    """
    if not (hits > 0 and rate > 0 and math.isfinite(rate)):
        return False
    revolutions = hits / rate
    low = float(stats.poisson.cdf(hits, revolutions))
    high = float(stats.poisson.sf(hits - 1, revolutions))
    return min(low, high) >= ONE_PER_REV_P / 2.0


def resolve_causes(
    features: list[str], context: str | None = None, open_causes: Collection[str] = ()
) -> dict[str, str]:
    """The probable cause of each feature that met the alarm rule together.

    Parameters
    ----------
    features : list of str
        Features whose X-of-Y rule is met at one recording.
    context : str, optional
        What the recording's impacts say (:func:`impact_context`): the cause
        of an impulsive feature when no more specific cause is present. When
        an impulsive feature is among ``features``, this cause is present too
        and explains what it explains: on the demo's rail obstacle the
        knocks' spectrum raised an unexplained peak, named ``bearing`` while
        the impulsive features beside it were named ``obstruction``.
    open_causes : collection of str
        Causes of the conveyor's alarms still open: present as well (an
        obstruction found days ago still knocks).

    Returns
    -------
    dict of str to str
        Feature to cause: its own (:data:`~chaintwin.diagnose.features.FEATURES`),
        unless a more specific cause present among the others explains it
        (:func:`explaining_causes`).
    """
    own = {f: feature_spec(f).cause or "unknown" for f in features}
    present = set(own.values()) | set(open_causes)
    if IMPULSIVE in present and context not in (None, IMPULSIVE, "payload_event"):
        present.add(context)
    out: dict[str, str] = {}
    for f, cause in own.items():
        key = (
            "comb"
            if f.startswith("comb_")
            else "mode"
            if f.startswith("mode_")
            else IMPULSIVE
            if cause == IMPULSIVE
            else f
        )
        for specific in explaining_causes(key):
            if specific in present:
                cause = specific
                break
        if cause == IMPULSIVE:
            cause = context or "unknown"
            if cause == IMPULSIVE and f.startswith("impact_"):
                # impacts met the rule, none with a wear pattern: events of operation
                cause = "payload_event"
        out[f] = cause
    return out


def explaining_causes(key: str) -> tuple[str, ...]:
    """The more specific causes that explain a feature's rise, in :data:`EXPLAINING_ORDER`.

    Read from the fault table (:func:`~chaintwin.simulate.faults.fault_types`):
    every alarmed cause whose faults move the feature, but the feature's own
    cause. An obstruction's bump, passed once in a scope, is an impulse whose
    spectrum spreads over the shaft lines too; a worn sprocket's knocks raise
    the tooth-pass lines an elongated chain raises, and more.

    Parameters
    ----------
    key : str
        A feature's name, ``comb`` for every ``comb_<shaft>``, ``mode`` for
        every ``mode_<line>``, ``impulsive`` for every feature of
        :data:`~chaintwin.diagnose.features.IMPULSIVE` cause.
    """
    name = key + "_" if key in ("comb", "mode") else key
    own = IMPULSIVE if key == IMPULSIVE else feature_spec(name).cause if is_tracked(name) else None
    movers: list[str] = []
    for t in fault_types():
        cause = t.cause
        if cause is not None and t.alarmed and cause != own and key in t.moves:
            movers += [] if cause in movers else [cause]
    rank = {c: i for i, c in enumerate(EXPLAINING_ORDER)}
    return tuple(sorted(movers, key=lambda c: rank.get(c, len(rank))))


def cause_priority(cause: str) -> int:
    return CAUSE_PRIORITY.index(cause) if cause in CAUSE_PRIORITY else len(CAUSE_PRIORITY)


def shaft_harmonic(
    order: float, shaft_order: float, tolerance: float, harmonics: int = OUTPUT_HARMONICS
) -> bool:
    """Whether an order is one of a shaft's first harmonics, within a tolerance.

    A damaged tooth of the gear unit's output stage (or its shaft) knocks once
    per output revolution: a comb at ``k/i`` that the characteristic lines do
    not list (the output shaft is too slow for the ``comb_`` features), so
    its tallest line shows as an unexplained peak. A bearing's defect orders
    (outer and inner race, ball spin: 2-7 per motor revolution) lie far above
    the output shaft's first harmonics on any gear unit with ``i >= 3``.

    Parameters
    ----------
    order, shaft_order : float
        The peak's order and the shaft's, per motor revolution.
    tolerance : float
        How close counts, in orders (about a spectral bin and a half).
    harmonics : int
        Highest harmonic counted.
    """
    if not (shaft_order > 0.0 and order > 0.0):
        return False
    k = round(order / shaft_order)
    return 1 <= k <= harmonics and abs(order - k * shaft_order) <= tolerance
