"""What the OPC UA server publishes per conveyor: node ids, units and values.

Nothing here imports asyncua: the values are worked out from the store
(:func:`read_conveyor`) as plain Python, and :mod:`chaintwin.live.opcua_server`
puts them into its address space.

Node ids
--------
Every node of the server's namespace (:data:`NAMESPACE_URI`) has a string
node id built from the conveyor id and the node's path below the conveyor,
so that it is the same after every restart and on every server of one store::

    Conveyors                                   the folder of all conveyors
    Conveyors/<id>                              the conveyor's object
    Conveyors/<id>/Monitoring/Payload           one of its values
    Conveyors/<id>/Monitoring/Features/friction/Value

``<id>`` is the conveyor id with every character other than ``A-Z a-z 0-9
- _ . ~`` written as ``%XX`` per UTF-8 byte (:func:`escape`), so an id
holding ``/`` or ``;`` cannot be mistaken for a path or break the node id's
text. The namespace's index is the server's to give: clients look it up by
its URI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any
from urllib.parse import quote

from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.baseline import regressor_of
from chaintwin.diagnose.features import feature_spec
from chaintwin.diagnose.monitor_state import MonitorState
from chaintwin.diagnose.records import as_number
from chaintwin.diagnose.verdict import (
    NE107,
    DeviationSeries,
    Verdict,
    deviation_series,
    verdict,
)
from chaintwin.errors import ChaintwinError
from chaintwin.read.profile import ConveyorProfile
from chaintwin.store.schema import AlarmRow, MonitorStateRow, ResultRow
from chaintwin.store.store import Store
from chaintwin.store.supersede import STANDING_RESULT

__all__ = [
    "DEVICE_HEALTH",
    "NAMESPACE_URI",
    "ROOT",
    "UNITS",
    "ConveyorKey",
    "ConveyorReader",
    "Unit",
    "Value",
    "conveyor_node_id",
    "conveyor_values",
    "escape",
    "node_id",
    "read_conveyor",
]

NAMESPACE_URI = "urn:chaintwin:results"
"""The URI of the namespace every chaintwin node lives in."""

ROOT = "Conveyors"
"""The string node id (and browse name) of the folder holding every conveyor."""

DEVICE_HEALTH: dict[str, int] = {
    "normal": 0,
    "failure": 1,
    "check_function": 2,
    "off_spec": 3,
    "maintenance_required": 4,
}
"""Each NE 107 category's value of OPC UA's ``DeviceHealthEnumeration`` (OPC 10000-100)."""

assert set(DEVICE_HEALTH) == set(NE107)


@dataclass(frozen=True, slots=True)
class Unit:
    """An engineering unit as OPC UA's ``EUInformation`` gives it (UNECE Recommendation 20).

    Attributes
    ----------
    code : str
        The UNECE common code (``KGM``); its ``UnitId`` is :attr:`unit_id`.
    symbol : str
        What a display shows (``kg``).
    name : str
        The unit's name.
    """

    code: str
    symbol: str
    name: str

    @property
    def unit_id(self) -> int:
        """OPC UA's ``UnitId`` of the code (OPC 10000-8: the code's characters, 8 bits each)."""
        out = 0
        for c in self.code:
            out = (out << 8) | ord(c)
        return out


UNITS: dict[str, Unit] = {
    "kg": Unit("KGM", "kg", "kilogram"),
    "m": Unit("MTR", "m", "metre"),
    "deg": Unit("DD", "°", "degree [unit of angle]"),
    "one": Unit("C62", "1", "one"),
    "N·m": Unit("NU", "N·m", "newton metre"),
    "kg·m²": Unit("B32", "kg·m²", "kilogram metre squared"),
    "rpm": Unit("RPM", "r/min", "revolutions per minute"),
    "s": Unit("SEC", "s", "second"),
    "d": Unit("DAY", "d", "day"),
    "J": Unit("JOU", "J", "joule"),
    "1/m": Unit("C92", "m⁻¹", "reciprocal metre"),
    "kg/m": Unit("KL", "kg/m", "kilogram per metre"),
}
"""The units the server uses, by the short name :class:`Value` carries."""

_FEATURE_UNITS = {"-": "one", "Nm": "N·m", "kg": "kg", "J": "J", "1/m": "1/m", "m": "m"}
"""A feature spec's display unit to a key of :data:`UNITS` (others: ``one``)."""

FIELDS = ("Value", "Expected", "Limit", "LowerLimit", "Deviation")
"""The values of each feature's folder (``Monitoring/Features/<feature>/...``)."""


@dataclass(frozen=True, slots=True)
class Value:
    """One published value.

    Attributes
    ----------
    value : Any
        float, int, str, datetime, list of str; None: not known now (``reason`` says why).
    kind : str
        ``double``, ``int``, ``uint``, ``string``, ``strings``, ``datetime`` or
        ``health`` (NE 107 as ``DeviceHealthEnumeration``).
    unit : str or None
        A key of :data:`UNITS` (numbers only).
    description : str
        What it is (the node's Description).
    reason : str or None
        Why ``value`` is None.
    """

    value: Any
    kind: str
    unit: str | None = None
    description: str = ""
    reason: str | None = None


def escape(conveyor: str) -> str:
    """A conveyor id as it stands in node ids: ``%XX`` for every UTF-8 byte outside
    ``A-Z a-z 0-9 - _ . ~``."""
    return quote(conveyor, safe="")


def conveyor_node_id(conveyor: str) -> str:
    """The string node id of a conveyor's object (``Conveyors/<escaped id>``)."""
    return f"{ROOT}/{escape(conveyor)}"


def node_id(conveyor: str, path: str) -> str:
    """The string node id of the node at ``path`` (``Monitoring/Payload``) below a conveyor."""
    return f"{conveyor_node_id(conveyor)}/{path}"


def _time(text: Any) -> datetime | None:
    if not text:
        return None
    try:
        out = datetime.fromisoformat(str(text))
    except ValueError:
        return None
    return out if out.tzinfo is not None else out.replace(tzinfo=UTC)


def _num(x: Any) -> float | None:
    if x is None or isinstance(x, bool):
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _double(x: Any, unit: str, description: str, reason: str) -> Value:
    v = _num(x)
    return Value(v, "double", unit, description, None if v is not None else reason)


def identification(profile: ConveyorProfile) -> dict[str, Value]:
    """What the profile says, by path (``Identification/...``), in the profile's units."""
    return {
        "Identification/ConveyorId": Value(profile.id, "string", None, "The conveyor id"),
        "Identification/BeltLength": Value(
            profile.belt.length_m, "double", "m", "Belt length (centre to centre)"
        ),
        "Identification/Incline": Value(
            profile.belt.incline_deg, "double", "deg", "Incline (positive: conveying up)"
        ),
        "Identification/BeltMassPerLength": Value(
            profile.belt.mass_per_m_kg, "double", "kg/m", "Belt mass per metre"
        ),
        "Identification/GearRatio": Value(
            profile.gear.ratio, "double", "one", "Gear ratio (motor turns per sprocket turn)"
        ),
        "Identification/GearEfficiency": Value(
            profile.gear.efficiency, "double", "one", "Gear efficiency"
        ),
        "Identification/SprocketPitchDiameter": Value(
            profile.sprocket.pitch_diameter_m, "double", "m", "Drive sprocket pitch diameter"
        ),
        "Identification/SprocketTeeth": Value(
            profile.sprocket.teeth,
            "uint",
            "one",
            "Drive sprocket teeth",
            None if profile.sprocket.teeth is not None else "not in the profile",
        ),
        "Identification/MotorInertia": Value(
            profile.motor.inertia_kgm2, "double", "kg·m²", "Motor rotor inertia"
        ),
        "Identification/MotorNominalTorque": _double(
            profile.motor.nominal_torque_nm, "N·m", "Motor nominal torque", "not in the profile"
        ),
        "Identification/MotorNominalSpeed": _double(
            profile.motor.nominal_speed_rpm, "rpm", "Motor nominal speed", "not in the profile"
        ),
    }


def _remaining(forecasts: list[dict[str, Any]]) -> tuple[dict[str, Any] | None, str]:
    """The forecast crossing its limit first (by its expected remaining life), or the reason."""
    with_life = [
        f
        for f in forecasts
        if isinstance(f.get("remaining_life_days"), dict)
        and _num(f["remaining_life_days"].get("expected")) is not None
    ]
    if not with_life:
        why = "no feature is forecast to reach its limit" if forecasts is not None else ""
        return None, why or "no forecast stored yet"
    first = min(with_life, key=lambda f: float(f["remaining_life_days"]["expected"]))
    return first, ""


def conveyor_values(
    profile: ConveyorProfile,
    judged: Verdict,
    state: MonitorState | None,
    latest: dict[str, Any] | None,
    open_alarms: list[dict[str, Any]],
    forecasts: list[dict[str, Any]] | None,
    series: DeviationSeries | None = None,
) -> dict[str, Value]:
    """Every value of a conveyor's object, by path below it.

    Parameters
    ----------
    profile : ConveyorProfile
        Its profile (``Identification``).
    judged : Verdict
        Its verdict (``DeviceHealth``, ``Monitoring/Health``, the health index).
    state : MonitorState or None
        Its health model (the features' baseline bands); None: none readable.
    latest : dict or None
        Its latest result's content with ``recorded_at`` (None: none yet).
    open_alarms : list of dict
        Its alarms not closed (``cause``, ``feature``).
    forecasts : list of dict or None
        Its stored forecasts (:mod:`chaintwin.store.derived`); None: never computed.
    series : DeviationSeries, optional
        ``deviation_series(state)`` when worked out already (the features' deviations).
    """
    out = identification(profile)
    no_rec = "no recording yet"
    res = latest or {}
    out["Monitoring/LastRecordedAt"] = Value(
        _time(res.get("recorded_at")),
        "datetime",
        None,
        "When the latest recording was made (UTC)",
        None if _time(res.get("recorded_at")) else no_rec,
    )
    out["Monitoring/Payload"] = _double(
        res.get("payload_kg"),
        "kg",
        "Payload on the belt at the latest recording",
        str(res.get("payload_reason") or "not weighed") if latest else no_rec,
    )
    out["Monitoring/PayloadUncertainty"] = _double(
        res.get("uncertainty_kg"),
        "kg",
        "One standard uncertainty of Payload (drift and model error included)",
        "no uncertainty for this payload" if latest else no_rec,
    )
    out["Monitoring/Tlf"] = _double(
        res.get("tlf"),
        "one",
        "Torque load factor of the latest recording",
        "not computed for this recording" if latest else no_rec,
    )
    out["Monitoring/Health"] = Value(
        judged.health, "string", None, "chaintwin's verdict (ok, watch, alarm, learning, ...)"
    )
    out["Monitoring/HealthSince"] = Value(
        _time(judged.health_since),
        "datetime",
        None,
        "Since when Health holds",
        None if _time(judged.health_since) else "not known",
    )
    out["Monitoring/HealthIndex"] = _double(
        judged.health_index,
        "one",
        "Largest normalised deviation of a feature (0 baseline, 1 alarm limit)",
        f"no baseline judges the recordings ({judged.health})",
    )
    out["Monitoring/WorstFeature"] = Value(
        judged.worst_feature,
        "string",
        None,
        "The feature of HealthIndex",
        None if judged.worst_feature else "no baseline judges the recordings",
    )
    first, why = _remaining(forecasts or [])
    life = (first or {}).get("remaining_life_days") or {}
    why = why if forecasts is not None else "no forecast stored yet"
    out["Monitoring/RemainingLife"] = _double(
        life.get("expected"), "d", "Expected days until a feature reaches its alarm limit", why
    )
    out["Monitoring/RemainingLifeEarliest"] = _double(
        life.get("earliest"), "d", "Earliest end of RemainingLife's band", why or "no band"
    )
    out["Monitoring/RemainingLifeLatest"] = _double(
        life.get("latest"), "d", "Latest end of RemainingLife's band", why or "beyond the horizon"
    )
    out["Monitoring/RemainingLifeFeature"] = Value(
        None if first is None else str(first.get("feature")),
        "string",
        None,
        "The feature RemainingLife is of",
        why or None,
    )
    out["Monitoring/OpenAlarmCount"] = Value(
        len(open_alarms), "uint", "one", "Alarms not closed (open, acknowledged, shelved)"
    )
    out["Monitoring/AlarmCauses"] = Value(
        sorted({str(a.get("cause")) for a in open_alarms if a.get("cause")}),
        "strings",
        None,
        "Probable causes of the alarms not closed",
    )
    out["DeviceHealth"] = Value(
        DEVICE_HEALTH[judged.ne107], "health", None, "NAMUR NE 107 status (DeviceHealthEnumeration)"
    )
    out["DeviceHealthSince"] = Value(
        _time(judged.ne107_since),
        "datetime",
        None,
        "Since when DeviceHealth holds",
        None if _time(judged.ne107_since) else "not known",
    )
    out.update(_features(state, res, series))
    return out


def _features(
    state: MonitorState | None, latest: dict[str, Any], series: DeviationSeries | None = None
) -> dict[str, Value]:
    """Each monitored feature's latest value, baseline band and deviation (``series``:
    the state's deviation series, when worked out already)."""
    if state is None or not state.baselines:
        return {}
    z_limit = state.settings.z_limit
    feats = latest.get("features") or {}
    devs = (deviation_series(state) if series is None else series).latest()
    out: dict[str, Value] = {}
    for name, fb in state.baselines.items():
        spec = feature_spec(name)
        if spec.cause is None:
            continue
        unit = _FEATURE_UNITS.get(spec.unit, "one")
        base = f"Monitoring/Features/{name}/"
        p = as_number(feats.get(regressor_of(name, fb)))
        at = p if math.isfinite(p) else fb.mean_payload_kg
        value = as_number(feats.get(name))
        no_value = "not in the latest recording" if feats else "no recording yet"
        out[base + "Value"] = _double(value, unit, f"{name} of the latest recording", no_value)
        out[base + "Expected"] = _double(
            fb.expected(at), unit, f"Baseline of {name} at the recording's payload", "no baseline"
        )
        out[base + "Limit"] = _double(
            fb.limit(z_limit, spec.min_rel, payload_kg=at),
            unit,
            f"Upper alarm limit of {name}",
            "no limit",
        )
        two_sided = spec.two_sided and fb.slope == 0.0
        out[base + "LowerLimit"] = _double(
            fb.lower_limit(z_limit, spec.min_rel, payload_kg=at) if two_sided else None,
            unit,
            f"Lower alarm limit of {name}",
            "one-sided: only a rise counts",
        )
        out[base + "Deviation"] = _double(
            devs.get(name),
            "one",
            f"{name}'s normalised deviation (0 baseline, 1 alarm limit; median of the latest)",
            "no judged recording yet",
        )
    return out


def _readable_state(store: Store, conveyor: str, profile: ConveyorProfile) -> MonitorState | None:
    """The conveyor's health model, when stored, readable and made with this profile."""
    with Session(store.engine) as s:
        row = s.get(MonitorStateRow, conveyor)
        data = None if row is None else dict(row.state)
    if data is None:
        return None
    try:
        state = MonitorState.from_dict(data, source=f"conveyor {conveyor}")
    except (ChaintwinError, KeyError, TypeError, ValueError):
        return None
    return state if state.profile_sha256 == profile.content_hash() else None


def read_conveyor(store: Store, conveyor: str) -> dict[str, Value] | None:
    """Every value of a conveyor's object read from the store (None: no such conveyor).

    Reads its profile, latest result (not refused), alarms not closed, health
    model and stored forecasts: five small reads and the verdict's work.
    """
    return ConveyorReader(store).read(conveyor)


ConveyorKey = tuple[Any, Any, Any, Any]
"""What a conveyor's values depend on: its profile's hash, its health model's version,
when its forecasts were computed and its number of open alarms."""


@dataclass
class _Parts:
    """What a conveyor's values were worked out from, by the key part each depends on."""

    profile_sha: Any
    profile: ConveyorProfile
    health: tuple[Any, Any]
    state: MonitorState | None
    series: DeviationSeries | None
    judged: Verdict
    latest: dict[str, Any] | None
    alarms: list[dict[str, Any]]
    computed_at: Any
    forecasts: list[dict[str, Any]] | None


class ConveyorReader:
    """Reads conveyors' values from the store, again only the parts whose key changed.

    A recording changes the health model's version (the latest result, the
    verdict, the features and the alarms are read and worked out again); the
    forecasts' refit that follows changes only when they were computed (only
    they are read again); a new profile changes everything.
    """

    def __init__(self, store: Store) -> None:
        self.store = store
        self._parts: dict[str, _Parts] = {}

    def forget(self, conveyor: str) -> None:
        """Drop what is kept of a conveyor (it left the store)."""
        self._parts.pop(conveyor, None)

    def read(self, conveyor: str, key: ConveyorKey | None = None) -> dict[str, Value] | None:
        """Every value of a conveyor's object (None: no such conveyor).

        ``key``: the conveyor's :data:`ConveyorKey` as read just before; the parts
        read for an earlier key are used again where their part of it is the same
        (None: everything is read, nothing kept).
        """
        from chaintwin.store.derived import read_derived

        old = self._parts.get(conveyor) if key is not None else None
        sha, version, computed_at, open_alarms = key if key is not None else (None,) * 4
        if old is not None and old.profile_sha == sha:
            profile = old.profile
        else:
            old = None  # a new profile: every value again
            stored = self.store.profile(conveyor)
            if stored is None:
                self.forget(conveyor)
                return None
            profile = stored
        if old is not None and old.health == (version, open_alarms):
            state, series, judged = old.state, old.series, old.judged
            latest, alarms = old.latest, old.alarms
        else:
            state = _readable_state(self.store, conveyor, profile)
            series = deviation_series(state) if state is not None and state.baselines else None
            judged = verdict(state, series=series)
            latest, alarms = _latest_result(self.store, conveyor)
        if old is not None and old.computed_at == computed_at:
            forecasts = old.forecasts
        else:
            derived = read_derived(self.store, conveyor)
            forecasts = None if derived is None else list(derived.content.get("forecasts") or [])
        if key is not None:
            self._parts[conveyor] = _Parts(
                sha,
                profile,
                (version, open_alarms),
                # its baselines and settings are what the values need again: its history
                # (up to the store's 300 recordings per conveyor) is not kept
                None if state is None else replace(state, history=[]),
                series,
                judged,
                latest,
                alarms,
                computed_at,
                forecasts,
            )
        return conveyor_values(profile, judged, state, latest, alarms, forecasts, series)


def _latest_result(
    store: Store, conveyor: str
) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """A conveyor's latest result (not refused, not superseded; None: none yet) and its
    alarms not closed."""
    with Session(store.engine) as s:
        row = s.execute(
            select(ResultRow.recorded_at, ResultRow.payload_kg, ResultRow.tlf, ResultRow.content)
            .where(
                ResultRow.conveyor_id == conveyor, ResultRow.status != "refused", STANDING_RESULT
            )
            .order_by(ResultRow.id.desc())
            .limit(1)
        ).first()
        alarms = [
            {"cause": a.cause, "feature": a.feature}
            for a in s.scalars(
                select(AlarmRow).where(
                    AlarmRow.conveyor_id == conveyor, AlarmRow.status != "closed"
                )
            )
        ]
    latest = None
    if row is not None:
        latest = dict(row.content or {})
        latest.update(recorded_at=row.recorded_at, payload_kg=row.payload_kg, tlf=row.tlf)
    return latest, alarms
