"""Probable causes: which fault a feature's rise points to, most specific first."""

from __future__ import annotations

from .features import feature_spec

__all__ = ["CAUSE_PRIORITY", "EXPLAINED_BY", "cause_priority", "resolve_causes"]

CAUSE_PRIORITY: tuple[str, ...] = (
    "obstruction",
    "elongation",
    "gear",
    "bearing",
    "lubrication",
    "friction",
)
"""Causes from the most specific to the least: a specific fault also moves
the general features (an obstruction raises the mean friction, an elongated
chain's articulation raises friction, a broken tooth raises the broadband
residual), so those are read as the specific fault when it is present."""

EXPLAINED_BY: dict[str, tuple[str, ...]] = {
    "friction": ("obstruction", "elongation"),
    "residual_std": ("obstruction", "gear", "elongation"),
    "residual_kurtosis": ("obstruction",),
    "crest_factor": ("obstruction",),
    "unexplained_peak": ("obstruction", "gear"),
    "comb": ("obstruction",),
}
"""Which more specific causes explain a feature's rise (``comb`` stands for
every ``comb_<shaft>``): an obstruction's bump, passed once in a scope, is
an impulse whose spectrum spreads over the shaft lines too."""


def resolve_causes(features: list[str]) -> dict[str, str]:
    """The probable cause of each feature that met the alarm rule together.

    Parameters
    ----------
    features : list of str
        Features whose X-of-Y rule is met at one recording.

    Returns
    -------
    dict of str to str
        Feature to cause: its own (:data:`~chaintwin.diagnose.features.FEATURES`),
        unless a more specific cause present among the others explains it
        (:data:`EXPLAINED_BY`).
    """
    own = {f: feature_spec(f).cause or "unknown" for f in features}
    present = set(own.values())
    out: dict[str, str] = {}
    for f, cause in own.items():
        for specific in EXPLAINED_BY.get("comb" if f.startswith("comb_") else f, ()):
            if specific in present:
                cause = specific
                break
        out[f] = cause
    return out


def cause_priority(cause: str) -> int:
    return CAUSE_PRIORITY.index(cause) if cause in CAUSE_PRIORITY else len(CAUSE_PRIORITY)
