"""What a report shows, gathered from the results store.

A conveyor's page is built from its stored results (one per recording), its
health model (baselines, alarms, forecasts), its maintenance events and a
few of its stored recordings rebuilt from their samples (the latest one
against the model; a spread of recordings for the spectrum waterfall).

Trend values are shown as the health model judges them: each value is moved
to the baseline's mean payload with its margin to the alarm limit kept in
proportion (:func:`_at_mean_payload`), so that one line and one limit hold
for every recording and a point lies above the drawn limit exactly when the
health model found it above its own.
"""

from __future__ import annotations

import math
import statistics
import threading
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime
from functools import cached_property
from itertools import chain
from operator import itemgetter
from typing import Any

import numpy as np

from chaintwin._types import FloatArray
from chaintwin.diagnose.baseline import regressor_of
from chaintwin.diagnose.features import FeatureSpec, feature_spec
from chaintwin.diagnose.health import FeatureBaseline
from chaintwin.diagnose.monitor_state import MonitorState, derived_inputs, read_health
from chaintwin.diagnose.records import Alarm, Event
from chaintwin.diagnose.verdict import Verdict
from chaintwin.diagnose.verdict import verdict as verdict_of
from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.identify.calibration import Calibration
from chaintwin.model.rigid import model_torque, motoring_mask
from chaintwin.read.profile import ConveyorProfile
from chaintwin.read.recording import Recording
from chaintwin.store.derived import read_derived, refit
from chaintwin.store.store import Store

__all__ = [
    "RECENT",
    "WATERFALL_RECORDINGS",
    "ConveyorData",
    "FeatureTrend",
    "HealthPart",
    "conveyor_data",
    "health_part",
]

WATERFALL_RECORDINGS = 40
"""Most recordings in a spectrum waterfall (spread evenly over the history)."""

RECENT = 10
"""Recordings the health index and the fleet's TLF figure look at (the latest)."""


@dataclass
class FeatureTrend:
    """One tracked feature over time, as the health model judges it.

    Attributes
    ----------
    name, cause, unit : str
        Feature, probable cause when it rises, unit of the values.
    index : list of int
        Positions of the values in the conveyor's results.
    values : list of float
        Values at the baseline's mean payload (NaN where unknown).
    exceeded : list of bool
        Whether the recording exceeded on this feature (against the baseline of its time).
    expected, limit : float or None
        Baseline level and alarm limit at the mean payload (None before a baseline).
    lower : float or None
        The lower alarm limit of a two-sided feature (a fall counts too), else None.
    """

    name: str
    cause: str
    unit: str
    index: list[int]
    values: list[float]
    exceeded: list[bool]
    expected: float | None
    limit: float | None
    before: list[bool] = field(default_factory=list)
    lower: float | None = None
    """Whether the recording was not judged against the current baseline: it came
    before it (judged against an earlier one) or formed it."""

    def health_index(self, recent: int = RECENT) -> float:
        """Median of ``(value − expected)/(limit − expected)`` over the latest values.

        0 at the baseline, 1 at the alarm limit; NaN without a baseline.
        """
        if self.expected is None or self.limit is None or self.limit <= self.expected:
            return math.nan
        current = [v for v, b in zip(self.values, self.before, strict=False) if not b]
        vals = [v for v in (current or self.values)[-recent:] if math.isfinite(v)]
        if not vals:
            return math.nan
        return (statistics.median(vals) - self.expected) / (self.limit - self.expected)


@dataclass
class ConveyorData:
    """Everything a conveyor's page shows."""

    profile: ConveyorProfile
    results: list[dict[str, Any]]
    times: list[datetime | None]
    alarms: list[Alarm]
    events: list[Event]
    summary: dict[str, Any]
    forecasts: list[dict[str, Any]]
    trends: list[FeatureTrend]
    calibration: Calibration | None
    baseline_since: str | None
    latest: Recording | None = None
    latest_result: dict[str, Any] | None = None
    waterfall: list[tuple[str, Recording]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    total: int | None = None
    """How many results the store holds for the conveyor (None: ``results`` are all of them)."""
    represents: list[int] | None = None
    """With ``max_points``: how many stored results each of ``results`` stands for."""
    verdict: Verdict = field(default_factory=lambda: verdict_of(None))
    """The conveyor's verdict (:func:`~chaintwin.diagnose.verdict.verdict`)."""
    features: list[str] | None = None
    """The names of the trends when they were not built (``trends`` is then empty);
    None: they were (:attr:`feature_names`)."""

    @property
    def feature_names(self) -> list[str]:
        """The names of the conveyor's trends (built or not)."""
        return [t.name for t in self.trends] if self.features is None else self.features

    @property
    def recordings(self) -> int:
        """How many (not refused) results the store holds for the conveyor."""
        return len(self.results) if self.total is None else self.total

    @cached_property
    def latest_model(self) -> FloatArray | None:
        """The calibrated rigid model's motor torque for the latest recording, Nm.

        None without a latest recording, a calibration or a payload estimate.
        """
        rec, cal = self.latest, self.calibration
        pay = (self.latest_result or {}).get("payload_kg")
        if rec is None or cal is None or not isinstance(pay, int | float) or not math.isfinite(pay):
            return None
        p = cal.parameters
        try:
            mot = motoring_mask(
                rec, drive_inertia_kgm2=p["J_d"], losses=(p["BmA"], p["BmB"], p["BmC"])
            )
            return model_torque(rec, cal.id_profile, p, float(pay), motoring=mot)
        except ChaintwinError:
            return None

    @property
    def status(self) -> str:
        """The verdict's ``health`` (:data:`~chaintwin.diagnose.verdict.HEALTH`)."""
        return self.verdict.health

    @property
    def health_index(self) -> float:
        """The largest feature health index (0 baseline, 1 alarm limit); NaN if none."""
        vals = [t.health_index() for t in self.trends]
        vals = [v for v in vals if math.isfinite(v)]
        return max(vals) if vals else math.nan

    @property
    def worst_feature(self) -> FeatureTrend | None:
        """The feature closest to (or furthest over) its limit."""
        best: tuple[float, FeatureTrend] | None = None
        for t in self.trends:
            h = t.health_index()
            if math.isfinite(h) and (best is None or h > best[0]):
                best = (h, t)
        return None if best is None else best[1]

    def recent_tlf(self, key: str = "tlf") -> float:
        """Median TLF of the latest :data:`RECENT` recordings with one (NaN if none).

        ``key``: ``tlf`` (sprocket work) or ``tlf_motor_shaft`` (motor-shaft work).
        """
        vals = [r[key] for r in self.results if r.get(key) is not None][-RECENT:]
        return float(statistics.median(vals)) if vals else math.nan

    def recent_payload(self) -> float:
        """Median payload of the latest :data:`RECENT` weighed recordings, kg."""
        vals = [r["payload_kg"] for r in self.results if r.get("payload_kg") is not None]
        return float(statistics.median(vals[-RECENT:])) if vals else math.nan

    def tlf_absence(self) -> str | None:
        """Why no recording gives a TLF, in words; None when one does (:meth:`recent_tlf`)."""
        if any(r.get("tlf") is not None for r in self.results):
            return None
        if not self.results:
            return "no recording yet"
        if not any(r.get("payload_kg") is not None for r in self.results):
            return (
                f"none of its {len(self.results)} recordings could be weighed (each "
                "recording's warnings say why); a TLF needs a weighed payload"
            )
        return (
            "its weighed payloads are under 1 kg or the belt did not travel; a TLF needs "
            "both (it is the work per kg carried per metre)"
        )

    def open_alarms(self) -> list[Alarm]:
        """Open alarms, acknowledged ones included."""
        return [a for a in self.alarms if a.is_open]


def _time(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)


def _number(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) else math.nan


def _numbers(xs: list[Any]) -> FloatArray:
    """Values as floats, NaN where not a number (as :func:`_number`, over a list at once)."""
    nan = math.nan
    return np.array([float(x) if isinstance(x, (int, float)) else nan for x in xs], dtype=float)


@dataclass
class _Series:
    """One alarmed feature's values as judged, with what its trend needs besides."""

    name: str
    spec: FeatureSpec
    baseline: FeatureBaseline | None
    index: list[int]
    values: FloatArray


_USAGE = "usage_since_baseline_t_km"
"""The feature the expected wear is a rate of (t·km carried since the baseline)."""

_NUMBERS = frozenset({int, float, bool, type(None)})


def _columns(feats_of: list[dict[str, Any]], keys: list[str]) -> dict[str, FloatArray]:
    """The values over the results (NaN for null) of the keys every result holds,
    converted at once, key by key; keys with a value neither a number nor null are
    left out (then taken one by one, as :func:`_numbers` does)."""
    counts = Counter(chain.from_iterable(feats_of))
    full = [k for k in keys if counts[k] == len(feats_of)]
    if not feats_of or not full:
        return {}
    getter = itemgetter(*full)
    rows = list(map(getter, feats_of)) if len(full) > 1 else [(x,) for x in map(getter, feats_of)]
    matrix = np.array(rows, dtype=object)
    out = {}
    for j, key in enumerate(full):
        column = matrix[:, j]
        if set(map(type, column)) <= _NUMBERS:
            out[key] = column.astype(float)  # null: NaN
    return out


def _judged_series(
    feats_of: list[dict[str, Any]],
    baselines: dict[str, FeatureBaseline],
    z_limit: float,
    expected_wear: dict[str, float] | None,
) -> list[_Series]:
    """Each alarmed feature's values as judged (NaN where unknown), built column by
    column over the results' ``features``; a feature never known is left out."""
    wear = expected_wear or {}
    # in order of first appearance; the features a cause is known for are alarmed
    first_seen = dict.fromkeys(chain.from_iterable(feats_of))
    names = [k for k in first_seen if feature_spec(k).cause is not None]
    if not names:
        return []
    regressors = {
        name: regressor_of(name, fb) for name in names if (fb := baselines.get(name)) is not None
    }
    # the features every result holds (as a rule all but a few) converted at once
    columns = _columns(
        feats_of, list(dict.fromkeys([*names, _USAGE, *filter(None, regressors.values())]))
    )

    def column(key: str, idx: list[int] | None) -> FloatArray:
        """``key``'s values at the results ``idx`` (None: all of them), NaN where absent."""
        full = columns.get(key)
        if full is not None:
            return full if idx is None else full[idx]
        at = feats_of if idx is None else [feats_of[k] for k in idx]
        return _numbers([feats.get(key) for feats in at])

    used = column(_USAGE, None)
    every = list(range(len(feats_of)))
    out = []
    for name in names:
        spec = feature_spec(name)
        fb = baselines.get(name)
        if name in columns:
            idx: list[int] | None = None
            index = every
        else:
            idx = index = [k for k, feats in enumerate(feats_of) if name in feats]
        values = column(name, idx)
        if name in wear:  # the expected wear (rate × usage since the baseline) taken off
            at_use = used if idx is None else used[idx]
            known = np.isfinite(at_use)
            values = np.where(known, values - wear[name] * np.where(known, at_use, 0.0), values)
        if fb is not None:  # all the feature's values at once
            regressor = regressors[name]
            payloads = column(regressor, idx) if regressor else np.full(len(index), math.nan)
            values = _at_mean_payload(fb, values, payloads, z_limit, spec)
        if np.isfinite(values).any():  # else never known (a retired feature such as belt_bump)
            out.append(_Series(name, spec, fb, index, values))
    return out


def _trend_names(
    results: list[dict[str, Any]],
    baselines: dict[str, FeatureBaseline],
    z_limit: float,
    expected_wear: dict[str, float] | None = None,
) -> list[str]:
    """The names of :func:`_trends`' trends, without building them."""
    feats_of = [r.get("features") or {} for r in results]
    return [s.name for s in _judged_series(feats_of, baselines, z_limit, expected_wear)]


def _trends(
    results: list[dict[str, Any]],
    baselines: dict[str, FeatureBaseline],
    z_limit: float,
    baseline_since: str | None,
    expected_wear: dict[str, float] | None = None,
) -> list[FeatureTrend]:
    """Each alarmed feature's series as judged: the profile's expected wear
    (rate × ``usage_since_baseline_t_km``) taken off, moved to the baseline's
    mean payload (:func:`_at_mean_payload`)."""
    feats_of = [r.get("features") or {} for r in results]
    series = _judged_series(feats_of, baselines, z_limit, expected_wear)
    if not series:
        return []
    exceeded_of = [r.get("exceeded") or () for r in results]
    # the baseline's own recordings are not judged against it either
    before_of = [
        bool(
            r.get("status") == "baseline"
            or (baseline_since and (at := r.get("recorded_at")) and at < baseline_since)
        )
        for r in results
    ]
    out = []
    for s in series:
        fb, spec, name = s.baseline, s.spec, s.name
        out.append(
            FeatureTrend(
                name=name,
                cause=spec.cause or "",
                unit=spec.unit,
                index=s.index,
                values=s.values.tolist(),
                exceeded=[name in exceeded_of[k] for k in s.index],
                expected=None if fb is None else fb.expected(fb.mean_payload_kg),
                limit=None if fb is None else fb.limit(z_limit, spec.min_rel),
                lower=(
                    fb.lower_limit(z_limit, spec.min_rel)
                    if fb is not None and spec.two_sided and fb.slope == 0.0
                    else None
                ),
                before=[before_of[k] for k in s.index],
            )
        )
    return out


def _at_mean_payload(
    fb: FeatureBaseline,
    values: FloatArray,
    payloads_kg: FloatArray,
    z_limit: float,
    spec: FeatureSpec,
) -> FloatArray:
    """Values moved to the baseline's mean payload, each margin to the limit kept in proportion.

    The health model judges a value against the baseline line and limit at
    the recording's own payload (the mean payload when its estimate is
    missing, NaN). Mapping ``e(p) → e(p̄)`` and ``L(p) → L(p̄)`` linearly keeps
    every point on the same side of the one drawn limit as it was judged.
    One value per payload (kg), feature units in and out.
    """
    p = np.where(np.isfinite(payloads_kg), payloads_kg, fb.mean_payload_kg)
    e_p = fb.expected_at(p)
    e_m = fb.expected(fb.mean_payload_kg)
    # above the line (or one-sided): in proportion to the upper limit's margin (the limit
    # less the line, computed as such)
    span_p = (e_p + fb.margin_at(e_p, z_limit, spec.min_rel)) - e_p
    span_m: FloatArray = np.full_like(e_p, fb.limit(z_limit, spec.min_rel) - e_m)
    if spec.two_sided and fb.slope == 0.0:  # a fall: in proportion to the lower limit's margin
        falls = values < e_p
        bottom = -math.inf if fb.bottom_residual is None else -fb.bottom_residual
        lower_span = np.maximum(np.maximum(z_limit * fb.scale, spec.min_rel * np.abs(e_p)), bottom)
        span_p = np.where(falls, e_p - (e_p - lower_span), span_p)
        span_m = np.where(falls, e_m - fb.lower_limit(z_limit, spec.min_rel), span_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = e_m + (values - e_p) * span_m / span_p
    return np.asarray(np.where(span_p <= 0.0, values - e_p + e_m, scaled), dtype=float)


def _spread(n: int, k: int) -> list[int]:
    """``k`` positions spread evenly over ``range(n)``, the last included."""
    if n <= k:
        return list(range(n))
    return sorted({round(float(x)) for x in np.linspace(0, n - 1, k)})


@dataclass
class HealthPart:
    """What a conveyor's page takes from its health model (:func:`health_part`).

    Attributes
    ----------
    summary : dict
        :func:`~chaintwin.diagnose.monitor_state.read_health`'s summary, with
        ``forecasts_as_of`` when the forecasts are the stored ones.
    forecasts : list of dict
        The trend forecasts (``summary["forecasts"]``).
    baselines : dict
        Each feature's baseline.
    z_limit : float
        The alarm limit in standard deviations.
    baseline_since : str or None
        When the current baseline starts (ISO 8601).
    judged : MonitorState or None
        The health model, when readable and made with the conveyor's profile.
    calibration : Calibration or None
        The health model's calibration.
    notes : list of str
        Why the health model could not be read.
    inputs : str or None
        :func:`~chaintwin.diagnose.monitor_state.derived_inputs` of the health
        model (None: none, or not readable).
    """

    summary: dict[str, Any] = field(default_factory=lambda: {"baseline": {"complete": False}})
    forecasts: list[dict[str, Any]] = field(default_factory=list)
    baselines: dict[str, FeatureBaseline] = field(default_factory=dict)
    z_limit: float = 5.0
    baseline_since: str | None = None
    judged: MonitorState | None = None
    calibration: Calibration | None = None
    notes: list[str] = field(default_factory=list)
    inputs: str | None = None


def health_part(
    store: Store,
    conveyor: str,
    profile: ConveyorProfile,
    *,
    stored_forecasts: bool = False,
    forecast_bands: bool = False,
) -> tuple[MonitorState | None, HealthPart]:
    """A conveyor's health model as stored (None: none, or damaged) and what its
    page takes from it (:func:`conveyor_data`'s ``stored_forecasts`` and
    ``forecast_bands``); the monitor is not rebuilt.

    With ``stored_forecasts`` (the web pages) both are kept in the process
    and read again only when the health model's version (raised by every
    write of it), the stored forecasts (when they were computed) or the
    profile change: one query tells. What is returned then is shared: read
    it, never change it.
    """
    if not stored_forecasts:
        return _health_part(store, conveyor, profile, stored_forecasts, forecast_bands)
    from chaintwin.store.queries import health_version

    key = (
        store.cache_key,
        conveyor,
        profile.content_hash(),
        forecast_bands,
        health_version(store, conveyor),
    )
    kept = _HEALTH.get(key)
    if kept is not None:
        return kept
    found = _health_part(store, conveyor, profile, stored_forecasts, forecast_bands)
    if key[-1][1] is not None:  # forecasts stored before the read: they are the ones read
        with _HEALTH_LOCK:
            _keep(_HEALTH, key, found, _HEALTH_KEPT)
    return found


def _keep(cache: dict[tuple[Any, ...], Any], key: tuple[Any, ...], value: Any, most: int) -> None:
    """Keep ``value`` under ``key`` (whose last part is the version read): the entries
    of other versions of the same key go, so a conveyor under live ingest holds one
    entry; at ``most`` entries the first kept goes. Call it holding the cache's lock."""
    for old in [k for k in cache if k[:-1] == key[:-1]]:
        del cache[old]
    if len(cache) >= most:
        cache.pop(next(iter(cache)))
    cache[key] = value


_HEALTH: dict[tuple[Any, ...], tuple[MonitorState | None, HealthPart]] = {}
"""Per (store URL, conveyor, profile, bands, :func:`~chaintwin.store.queries.health_version`):
:func:`health_part`'s answer for the web pages."""

_HEALTH_KEPT = 32
"""Conveyors (and with or without bands) whose health part is kept (the first kept goes first)."""

_HEALTH_LOCK = threading.Lock()


def _health_part(
    store: Store,
    conveyor: str,
    profile: ConveyorProfile,
    stored_forecasts: bool,
    forecast_bands: bool,
) -> tuple[MonitorState | None, HealthPart]:
    """:func:`health_part`, read."""
    part = HealthPart()
    try:
        state = store.state(conveyor)
    except StoreError as exc:  # the page shows what else the store holds
        part.notes.append(f"health model not readable: {exc}")
        return None, part
    if state is not None:
        part.inputs = derived_inputs(state)
    if state is not None and state.profile_sha256 != profile.content_hash():
        part.notes.append(
            "health model not readable: it was made with another version of the profile"
        )
    elif state is not None:
        try:
            # forecasts are fitted after ingest, not per page: the pages read them
            # (a conveyor never refitted, in a store written before, is refitted
            # once here); a report fits them here, as the monitor says them
            derived = read_derived(store, conveyor) if stored_forecasts else None
            if stored_forecasts and derived is None:
                derived = refit(store, conveyor, state)
            health = read_health(
                state,
                bands=forecast_bands,
                derived=None if derived is None else derived.content,
            )
        except (ChaintwinError, KeyError, TypeError, ValueError) as exc:
            part.notes.append(f"health model not readable: {exc!r}")
        else:
            part.calibration = health.calibration
            part.summary = health.summary
            if derived is not None:
                part.summary["forecasts_as_of"] = derived.as_of(state, part.inputs)
            part.forecasts = part.summary["forecasts"]
            part.baselines = health.baselines
            part.z_limit = health.z_limit
            part.baseline_since = health.baseline_since
            part.judged = state
    return state, part


@dataclass(frozen=True)
class _PageRows:
    """What a conveyor's page and detail read from its results (:func:`conveyor_data`
    with ``max_points`` and without ``trends``)."""

    results: list[dict[str, Any]]
    """Shared by every request that finds them: read, never changed."""
    represents: list[int] | None
    total: int | None
    features: list[str]


_PAGE_ROWS: dict[tuple[Any, ...], _PageRows] = {}
"""Per (store URL, conveyor, bound, profile, :func:`~chaintwin.store.queries.read_version`):
the bounded results and the names of their trends. Kept in the process, read again when
the conveyor's newest result, number of results, health model or profile changes."""

_PAGE_ROWS_KEPT = 16
"""Conveyors whose page rows are kept (each their 200 results; the first kept goes first)."""

_PAGE_ROWS_LOCK = threading.Lock()


def conveyor_data(
    store: Store,
    conveyor: str,
    *,
    waterfall: int = WATERFALL_RECORDINGS,
    forecast_bands: bool = False,
    max_points: int | None = None,
    latest: bool = True,
    stored_forecasts: bool = False,
    known_verdict: Verdict | None = None,
    trends: bool = True,
) -> ConveyorData:
    """Gather a conveyor's page from the store.

    Parameters
    ----------
    store : Store
        The results store.
    conveyor : str
        Conveyor id.
    waterfall : int
        Most recordings rebuilt for the spectrum waterfall.
    forecast_bands : bool
        The forecasts carry their ``band`` (path and 90 % interval ahead).
    max_points : int, optional
        Read at most this many results (:func:`~chaintwin.store.queries.trend_rows`:
        the newest half in full, the older history thinned), so that the
        cost hardly grows with the history (the web pages); ``total`` then
        counts them all. At least ``2 * RECENT``, so that the newest
        :data:`RECENT` are read and the health index and status are those of
        every result. None: every result (the reports).
    latest : bool
        Rebuild the latest recording from its samples (``latest``,
        ``latest_result``); the web pages do not show it.
    stored_forecasts : bool
        Take the forecasts and wear rates as stored after ingest
        (:mod:`chaintwin.store.derived`) even when newer recordings came
        since (the web pages: ``summary["forecasts_as_of"]`` says how far
        behind); False: fit them here, as the monitor says them (the
        reports; nothing is written to the store).
    known_verdict : Verdict, optional
        The conveyor's verdict when the caller keeps it per version of the
        health model (:class:`~chaintwin.store.verdicts.VerdictCache`, the web
        service); None: worked out here from the model.
    trends : bool
        Build each feature's trend (``trends``); False: only name them
        (``features``; ``trends`` is then empty, and with it the health index
        and worst feature of :class:`ConveyorData`: the web's page and detail,
        whose verdict carries both). With ``max_points``, the bounded results
        and the trends' names are then kept in the process and read again only
        when the conveyor's newest result, number of results, health model
        (its version, raised by every write) or profile changes: the
        ``results`` of such a ConveyorData are shared, to be read only.

    Raises
    ------
    StoreError
        When the store does not hold the conveyor.
    """
    profile = store.profile(conveyor)
    if profile is None:
        raise StoreError(
            f"the store holds no conveyor '{conveyor}' "
            f"(it holds: {', '.join(store.conveyors()) or 'none'})"
        )
    total: int | None = None
    represents: list[int] | None = None
    kept: _PageRows | None = None
    key: tuple[Any, ...] | None = None
    if max_points is None:
        results = [r for r in store.results(conveyor) if "error" not in r]
    else:
        from chaintwin.store.queries import read_version, trend_rows

        # the newest RECENT at least in full: the health index and status are exact
        bound = max(max_points, 2 * RECENT)
        if not trends:  # the page and the detail: kept while nothing they show changes
            key = (
                store.cache_key,
                conveyor,
                bound,
                profile.content_hash(),
                read_version(store, conveyor),
            )
            kept = _PAGE_ROWS.get(key)
        if kept is not None:
            results, represents, total = kept.results, kept.represents, kept.total
        else:
            bounded = trend_rows(store, conveyor, bound)
            results, represents, total = bounded.results, bounded.represents, bounded.total
    _state, health = health_part(
        store,
        conveyor,
        profile,
        stored_forecasts=stored_forecasts,
        forecast_bands=forecast_bands,
    )
    calibration = health.calibration
    if calibration is None:
        calibration = store.calibration(conveyor)
    summary, forecasts, notes = health.summary, health.forecasts, health.notes
    baselines, z_limit, baseline_since = health.baselines, health.z_limit, health.baseline_since
    judged = health.judged
    data = ConveyorData(
        profile=profile,
        results=results,
        times=[_time(r.get("recorded_at")) for r in results],
        alarms=store.alarms(conveyor),
        events=store.events(conveyor),
        summary=summary,
        forecasts=forecasts,
        trends=(
            _trends(results, baselines, z_limit, baseline_since, profile.expected_wear)
            if trends
            else []
        ),
        calibration=calibration,
        baseline_since=baseline_since,
        notes=notes,
        total=total,
        represents=represents,
        verdict=verdict_of(judged) if known_verdict is None else known_verdict,
        features=None,
    )
    if not trends:
        if kept is None:
            kept = _PageRows(
                results,
                represents,
                total,
                _trend_names(results, baselines, z_limit, profile.expected_wear),
            )
            if key is not None:
                with _PAGE_ROWS_LOCK:
                    _keep(_PAGE_ROWS, key, kept, _PAGE_ROWS_KEPT)
        data.features = list(kept.features)
    if not latest and waterfall <= 0:
        return data
    index = store.recording_index(conveyor)
    by_file = {r["file"]: r for r in results}
    if index:
        rid, name, _at = index[-1]
        data.latest = store.recording(rid)
        data.latest_result = by_file.get(name)
    for k in _spread(len(index), waterfall):
        rid, _name, at = index[k]
        data.waterfall.append((at or f"#{k + 1}", store.recording(rid)))
    return data
