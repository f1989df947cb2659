"""Self-contained HTML reports: one page per conveyor and a fleet page.

A page holds its plots as PNG data URIs and its style inline: it opens
offline, from a mail attachment or a USB stick, with no network and no
other file. Pages are rendered with Jinja2 (autoescaped: file names and
maintenance notes come from users) and written atomically.

Sections of a conveyor page (their HTML ids, which tests and links use):
``summary``, ``alarms``, ``trends``, ``payload-tlf``, ``residuals``,
``waterfall``, ``latest``. Of the fleet page: ``ranking-health``,
``ranking-tlf``.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from jinja2 import Environment, PackageLoader, StrictUndefined

from chaintwin import __version__
from chaintwin.diagnose.alarm_kpis import KPI_DAYS, alarm_kpis
from chaintwin.diagnose.residuals import residual_analysis
from chaintwin.diagnose.verdict import HEALTH
from chaintwin.errors import ChaintwinError, StoreError
from chaintwin.identify.verification import verify_recording
from chaintwin.read.files import write_atomic
from chaintwin.store.engine import safe_url
from chaintwin.store.store import Store
from chaintwin.weigh.tlf import PUBLISHED_TLF, PUBLISHED_TLF_NOTE

from . import figures
from .data import RECENT, ConveyorData, conveyor_data

__all__ = [
    "CONVEYOR_SECTIONS",
    "FLEET_SECTIONS",
    "conveyor_page",
    "fleet_page",
    "page_names",
    "report_file_name",
    "write_folder",
    "write_page",
]

CONVEYOR_SECTIONS = (
    "summary",
    "alarms",
    "trends",
    "payload-tlf",
    "residuals",
    "waterfall",
    "latest",
)
"""HTML ids of a conveyor page's sections, in page order."""

FLEET_SECTIONS = ("ranking-health", "ranking-tlf", "alarm-kpis")
"""HTML ids of the fleet page's sections."""

RESIDUAL_COLUMNS = ("mean", "std", "rms", "max_abs", "kurtosis", "skewness", "crest_factor")
"""Residual statistics shown for the latest recording."""

_ENV = Environment(
    loader=PackageLoader("chaintwin.report", "templates"),
    autoescape=True,
    undefined=StrictUndefined,
    trim_blocks=True,
    lstrip_blocks=True,
)


def _fmt(x: Any, digits: int) -> str:
    if not isinstance(x, int | float) or not math.isfinite(x):
        return "-"
    return f"{x:.{digits}f}"


def _pct(x: Any) -> str:
    if not isinstance(x, int | float) or not math.isfinite(x):
        return "-"
    return f"{x:+.0%}"


_ENV.globals.update(fmt=_fmt, pct=_pct, version=__version__)


def report_file_name(conveyor: str) -> str:
    """File name of a conveyor's page: ``<id>.html``, other characters than ``A-Za-z0-9-_.`` → _."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in conveyor)
    if len(safe.encode()) > _NAME_BYTES:  # file systems allow 255 bytes a name
        digest = hashlib.sha256(conveyor.encode()).hexdigest()[:8]
        safe = safe.encode()[:_NAME_BYTES].decode(errors="ignore") + "-" + digest
    return f"{safe}.html"


_NAME_BYTES = 200
"""Longest page name before ``.html``, bytes (longer ones are cut, with a hash)."""


def page_names(conveyors: Sequence[str]) -> dict[str, str]:
    """File names of the conveyors' pages in one folder: distinct, none ``fleet.html``.

    Ids that map to the same file name (``a/b`` and ``a_b``) or to the fleet
    page's get a suffix (``-2``, ``-3``, ...) in sorted order of the ids.
    """
    used = {"fleet.html"}
    out: dict[str, str] = {}
    for cid in sorted(conveyors):
        name = report_file_name(cid)
        stem, k = name[: -len(".html")], 2
        while name.lower() in used:
            name, k = f"{stem}-{k}.html", k + 1
        used.add(name.lower())
        out[cid] = name
    return out


def _status_text(d: ConveyorData) -> str:
    opened = d.open_alarms()
    if opened:
        causes = sorted({a.cause for a in opened})
        return f"open alarm on {', '.join(causes)}"
    status = d.status
    if status in ("learning", "relearning"):
        return "baseline still being learned" + (
            " after maintenance" if status == "relearning" else ""
        )
    if status == "out_of_service":
        return "out of service: its recordings are not judged"
    if status == "no_data":
        return "no recording judged yet"
    if status == "shelved":
        return "its open alarms are shelved"
    if status == "watch":
        worst = d.worst_feature
        name = worst.name if worst else "a feature"
        return f"no alarm; {name} is near its limit (health index at least 0.7)"
    return "no alarm, every feature inside its limits"


def _description(d: ConveyorData) -> str:
    p = d.profile
    incline = f", {p.belt.incline_deg:g}° incline" if p.belt.incline_deg else ""
    return (
        f"chain belt conveyor, {p.belt.length_m:g} m belt{incline}, sprocket "
        f"{p.sprocket.pitch_diameter_m * 1e3:.0f} mm, gear ratio {p.gear.ratio:g}"
    )


def _calibration_text(d: ConveyorData) -> str:
    cal = d.calibration
    if cal is None:
        return "none yet"
    src = d.summary.get("calibration") or "store"
    mu, se = cal.parameters["mu"], cal.parameters.stderr("mu")
    return f"{src}; case {cal.case}; μ = {mu:.4f} ± {se:.4f}, {len(cal.recordings)} recordings"


def _baseline_text(d: ConveyorData) -> str:
    b = d.summary.get("baseline", {})
    if not b.get("complete"):
        return f"being learned ({b.get('recordings', 0)} recordings so far)"
    since = (b.get("since") or "")[:16]
    return f"{b.get('recordings')} recordings since {since or 'the start'}"


def _residual_table(d: ConveyorData) -> list[tuple[str, dict[str, Any]]]:
    model = d.latest_model
    if model is None or d.latest is None:
        return []
    try:
        rep = residual_analysis(d.latest, model)
    except ChaintwinError:
        return []
    rows = [("whole movement", rep.whole.to_dict())]
    rows += [(kind, s.to_dict()) for kind, s in rep.by_phase.items()]
    return rows


def _verification_table(d: ConveyorData) -> tuple[str, list[tuple[str, list[float | None]]]]:
    """The twin's REP against the latest recording (closed loop), whole and per phase.

    Returns the movement's name and rows ``(what, [speed mean, std, max|.|,
    torque mean, std, max|.|])`` in %; empty when it cannot be computed (no
    recording, calibration or payload; no set point; not starting at rest).
    """
    rec, cal = d.latest, d.calibration
    pay = (d.latest_result or {}).get("payload_kg")
    if rec is None or cal is None or not isinstance(pay, int | float) or not math.isfinite(pay):
        return "", []
    try:
        v = verify_recording(
            rec, cal.id_profile, calibration=cal, residual="closed-loop", payload_kg=float(pay)
        ).to_dict()
    except ChaintwinError:
        return "", []
    keys = ("rep_mean_pct", "rep_std_pct", "rep_absmax_pct")

    def cells(speed: dict[str, Any] | None, torque: dict[str, Any] | None) -> list[float | None]:
        return [(speed or {}).get(k) for k in keys] + [(torque or {}).get(k) for k in keys]

    rows = [("whole movement", cells(v["speed"], v["torque"]))]
    for ph in v["phases"]:
        what = f"{ph['kind']} {'fwd' if ph['direction'] > 0 else 'bwd'}"
        rows.append((what, cells(ph["speed"], ph["torque"])))
    return str(v["movement"]), rows


def conveyor_page(
    store: Store, conveyor: str, *, fleet_link: str | None = None
) -> tuple[str, ConveyorData]:
    """A conveyor's report page.

    Parameters
    ----------
    store : Store
        The results store.
    conveyor : str
        Conveyor id.
    fleet_link : str, optional
        Relative link to the fleet page, shown in the header.

    Returns
    -------
    (str, ConveyorData)
        The HTML and the data it was made from.

    Raises
    ------
    StoreError
        When the store does not hold the conveyor.
    """
    d = conveyor_data(store, conveyor)
    times = [t for t in d.times if t is not None]
    trend_figures = []
    for t in d.trends:
        uri = figures.trend_figure(d, t)
        if uri is not None:
            trend_figures.append({"name": t.name, "uri": uri})
    html = _ENV.get_template("conveyor.html.j2").render(
        d=d,
        made=datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        source=safe_url(store.url),
        fleet_link=fleet_link,
        description=_description(d),
        first=times[0].strftime("%Y-%m-%d %H:%M") if times else None,
        last=times[-1].strftime("%Y-%m-%d %H:%M") if times else None,
        status_text=_status_text(d),
        calibration_text=_calibration_text(d),
        baseline_text=_baseline_text(d),
        recent=RECENT,
        published_tlf=PUBLISHED_TLF,
        published_tlf_note=PUBLISHED_TLF_NOTE,
        trend_figures=trend_figures,
        payload_figure=figures.payload_tlf_figure(d),
        residual_figure=figures.residual_figure(d),
        residual_columns=RESIDUAL_COLUMNS,
        residual_table=_residual_table(d),
        verification=_verification_table(d),
        waterfall_figure=figures.waterfall_figure(d),
        waterfall_count=len(d.waterfall),
        campbell_figure=figures.campbell_figure(d),
        latest_figure=figures.latest_figure(d),
    )
    return html, d


@dataclass(frozen=True)
class FleetRow:
    """One conveyor on the fleet page."""

    id: str
    link: str | None
    status: str
    alarms: str
    health: float
    worst: str
    forecast: str
    recordings: int
    latest: str
    tlf: float
    payload: float


def _rank(x: float) -> float:
    return x if math.isfinite(x) else -math.inf


def _forecast_text(fc: dict[str, Any]) -> str:
    if fc.get("crossed"):
        return f"{fc['feature']}: crossed {str(fc['crosses_at'])[:16].replace('T', ' ')}"
    return f"{fc['feature']}: {str(fc['crosses_at'])[:10]}"


def _fleet_row(d: ConveyorData, links: Mapping[str, str] | None) -> FleetRow:
    opened = d.open_alarms()
    worst = d.worst_feature
    last = next((t for t in reversed(d.times) if t is not None), None)
    fc = sorted(d.forecasts, key=lambda f: str(f["crosses_at"]))
    alarms = ", ".join(
        f"{a.cause} ({a.feature}{', ack.' if a.acknowledged else ''})" for a in opened
    )
    return FleetRow(
        id=d.profile.id,
        link=None if links is None else links.get(d.profile.id),
        status=d.status,
        alarms=alarms or "-",
        health=math.nan if d.verdict.health_index is None else d.verdict.health_index,
        worst=worst.name if worst else "-",
        forecast=_forecast_text(fc[0]) if fc else "-",
        recordings=len(d.results),
        latest=last.strftime("%Y-%m-%d %H:%M") if last else "-",
        tlf=d.recent_tlf(),
        payload=d.recent_payload(),
    )


def fleet_page(
    store: Store,
    data: list[ConveyorData] | None = None,
    *,
    links: Mapping[str, str] | None = None,
) -> str:
    """The fleet page: conveyors ranked by health and by TLF; the alarm KPIs.

    The alarm KPIs cover the :data:`KPI_DAYS` days up to the latest recording.

    Parameters
    ----------
    store : Store
        The results store.
    data : list of ConveyorData, optional
        Gathered already (by :func:`conveyor_page`); else gathered here.
    links : Mapping of str to str, optional
        Conveyor id to the file name of its page beside the fleet page (no
        links without).
    """
    if data is None:
        data = [conveyor_data(store, c, waterfall=0) for c in store.conveyors()]
    if not data:
        raise StoreError(f"{safe_url(store.url)}: the store holds no conveyor yet")
    rows = [_fleet_row(d, links) for d in data]
    rows.sort(key=lambda r: (HEALTH.index(r.status), -_rank(r.health), r.id))
    by_tlf = sorted(rows, key=lambda r: (-_rank(r.tlf), r.id))
    latest = [t for d in data for t in d.times if t is not None]
    until = (max(latest) + timedelta(seconds=1)) if latest else datetime.now(UTC)
    if until.tzinfo is None:
        until = until.replace(tzinfo=UTC)
    kpis = alarm_kpis(store.alarms(), until - timedelta(days=KPI_DAYS), until)
    return _ENV.get_template("fleet.html.j2").render(
        kpis=kpis,
        kpi_days=KPI_DAYS,
        rows=rows,
        by_tlf=by_tlf,
        made=datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        source=safe_url(store.url),
        recent=RECENT,
        health_figure=figures.fleet_health_figure([r.id for r in rows], [r.health for r in rows]),
        tlf_figure=figures.fleet_tlf_figure([r.id for r in by_tlf], [r.tlf for r in by_tlf]),
        no_tlf=[(d.profile.id, why) for d in data if (why := d.tlf_absence()) is not None],
    )


def write_page(html: str, path: str | Path) -> Path:
    """Write a page atomically (a reader never sees half a page).

    Raises
    ------
    StoreError
        When it cannot be written (an older page there is left as it was).
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(
            f"out {target}: cannot make its folder ({exc.strerror or exc})", field="out"
        ) from None
    return write_atomic(
        target,
        html,
        what="report",
        error=lambda t, m: StoreError(f"out {t}: {m}", field="out"),
    )


def write_folder(store: Store, folder: str | Path) -> list[Path]:
    """Every conveyor's page and the fleet page (``fleet.html``, last in the list) into a folder.

    Raises
    ------
    StoreError
        When the store holds no conveyor, or a page cannot be written.
    """
    conveyors = store.conveyors()
    if not conveyors:
        raise StoreError(f"{safe_url(store.url)}: the store holds no conveyor yet")
    root = Path(folder)
    names = page_names(conveyors)
    written, data = [], []
    for cid in conveyors:
        html, d = conveyor_page(store, cid, fleet_link="fleet.html")
        written.append(write_page(html, root / names[cid]))
        data.append(d)
    written.append(write_page(fleet_page(store, data, links=names), root / "fleet.html"))
    return written
