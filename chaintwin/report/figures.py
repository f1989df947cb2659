"""The report's plots: matplotlib figures as PNG data URIs (the page needs no network).

Figures are drawn on the Agg canvas directly (no pyplot, no global state),
so reports can be built in worker processes and in tests. Every function
returns a ``data:image/png;base64,...`` URI, or None when there is nothing
to draw.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Sequence
from datetime import datetime
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from chaintwin._types import FloatArray
from chaintwin.diagnose.spectra import Spectrum, order_spectrum, welch_spectrum
from chaintwin.errors import ChaintwinError
from chaintwin.model.frequencies import apparent_order, characteristic_lines, line_orders
from chaintwin.read.recording import Recording
from chaintwin.units import RPM_TO_RAD_S

from .data import ConveyorData, FeatureTrend

__all__ = [
    "campbell_figure",
    "campbell_peaks",
    "fleet_health_figure",
    "fleet_tlf_figure",
    "latest_figure",
    "payload_tlf_figure",
    "residual_figure",
    "trend_figure",
    "waterfall_figure",
]

DPI = 96
"""Resolution of the PNGs, dots per inch."""

GRID_POINTS = 400
"""Points of the common axis a waterfall's spectra are interpolated onto."""


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _uri(fig: Figure) -> str:
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _x(data: ConveyorData) -> tuple[list[Any], str]:
    """The results' x positions: their times when every one has a time, else their numbers."""
    if data.times and all(t is not None for t in data.times):
        return list(data.times), "recorded at (UTC)"
    return list(range(1, len(data.results) + 1)), "recording number"


def _when(data: ConveyorData, text: str | None) -> Any:
    """An ISO time as an x position of the results axis (None when it cannot be placed)."""
    if text is None:
        return None
    xs, _label = _x(data)
    t = datetime.fromisoformat(text)
    if isinstance(xs[0], datetime):
        return t
    later = [k for k, rt in enumerate(data.times) if rt is not None and rt >= t]
    return xs[later[0]] if later else None


def _marks(ax: Axes, data: ConveyorData, feature: str | None = None) -> None:
    """Maintenance events (vertical lines) and alarm periods (shaded) on a time axis."""
    xs, _label = _x(data)
    end = xs[-1]
    for alarm in data.alarms:
        if feature is not None and alarm.feature != feature:
            continue
        start = _when(data, alarm.since)
        stop = _when(data, alarm.closed_at) or end
        if start is not None:
            ax.axvspan(start, stop, color="tab:red", alpha=0.08, linewidth=0)
    for ev in data.events:
        at = _when(data, ev.at)
        if at is not None:
            ax.axvline(at, color="tab:purple", linewidth=1.0, linestyle=":")
            ax.text(
                at,
                0.98,
                f" {ev.kind}",
                transform=ax.get_xaxis_transform(),
                fontsize=7,
                color="tab:purple",
                va="top",
            )


def _time_axis(ax: Axes, label: str) -> None:
    ax.set_xlabel(label)
    ax.grid(True, alpha=0.3)
    ax.tick_params(axis="x", labelrotation=20)


def trend_figure(data: ConveyorData, trend: FeatureTrend) -> str | None:
    """One feature over time: values, baseline, alarm limit, exceedances, alarms, events."""
    if not trend.values:
        return None
    xs, label = _x(data)
    fig = _figure(6.4, 3.0)
    ax = fig.add_subplot()
    x = [xs[k] for k in trend.index]
    v = np.asarray(trend.values, dtype=float)
    exc = np.asarray(trend.exceeded, dtype=bool)
    earlier = np.asarray(trend.before or [False] * len(x), dtype=bool)
    statuses = [data.results[k].get("status") for k in trend.index]
    base = np.asarray([s in ("baseline", "learning") for s in statuses]) & ~earlier
    exc &= ~earlier
    ok = ~exc & ~base & ~earlier
    ax.plot(x, v, color="0.75", linewidth=0.6, zorder=1)
    groups = (
        (earlier, 8, "0.85", "before the current baseline"),
        (base, 9, "0.5", "baseline"),
        (ok, 9, "tab:blue", "monitored"),
        (exc, 14, "tab:red", "exceeded"),
    )
    for mask, size, colour, what in groups:
        if mask.any():
            pts = np.flatnonzero(mask)
            ax.scatter([x[k] for k in pts], v[mask], s=size, color=colour, label=what)
    if trend.expected is not None and trend.limit is not None:
        current = np.flatnonzero(~earlier)
        start = x[int(current[0])] if current.size else x[0]
        ax.hlines(trend.expected, start, x[-1], color="tab:green", label="baseline level")
        ax.hlines(trend.limit, start, x[-1], color="tab:red", linestyle="--", label="alarm limit")
        if trend.lower is not None:
            ax.hlines(
                trend.lower, start, x[-1], color="tab:red", linestyle=":", label="lower limit"
            )
    _marks(ax, data, trend.name)
    unit = "" if trend.unit == "-" else f" [{trend.unit}]"
    ax.set_ylabel(f"{trend.name}{unit}")
    moves = "rises" if trend.lower is None else "rises or falls"
    ax.set_title(f"{trend.name} ({moves} with: {trend.cause})", fontsize=10)
    ax.margins(y=0.12)
    ax.legend(fontsize=7, loc="best", ncols=3)
    _time_axis(ax, label)
    return _uri(fig)


def payload_tlf_figure(data: ConveyorData) -> str | None:
    """Payload (with its standard uncertainty) and the transport loss factor over time."""
    xs, label = _x(data)
    pay = [
        (x, r["payload_kg"], r.get("uncertainty_kg") or 0.0)
        for x, r in zip(xs, data.results, strict=True)
        if r.get("payload_kg") is not None
    ]
    tlf = [(x, r["tlf"]) for x, r in zip(xs, data.results, strict=True) if r.get("tlf") is not None]
    if not pay and not tlf:
        return None
    fig = _figure(12.0, 3.4)
    ax1 = fig.add_subplot(1, 2, 1)
    if pay:
        ax1.errorbar(
            [p[0] for p in pay],
            [p[1] for p in pay],
            yerr=[p[2] for p in pay],
            fmt="o",
            markersize=3,
            linewidth=0.8,
            color="tab:blue",
        )
    else:
        _words(
            ax1, "no payload: no recording could be weighed\n(each recording's warnings say why)"
        )
    n = len(data.results)
    ax1.set_ylabel("payload [kg] (± 1 σ)")
    ax1.set_title("payload weighed from torque" + _left_out(n - len(pay), n), fontsize=10)
    _marks(ax1, data)
    _time_axis(ax1, label)
    ax2 = fig.add_subplot(1, 2, 2)
    if tlf:
        ax2.plot([t[0] for t in tlf], [t[1] for t in tlf], "o", markersize=3, color="tab:orange")
    else:
        _words(ax2, "no TLF: it needs a weighed payload of at least 1 kg\nand belt travel")
    ax2.set_ylabel("transport loss factor [-]")
    ax2.set_title(
        "TLF: work at the sprocket / (payload weight x distance)" + _left_out(n - len(tlf), n),
        fontsize=10,
    )
    _marks(ax2, data)
    _time_axis(ax2, label)
    return _uri(fig)


def _words(ax: Axes, text: str) -> None:
    """An empty panel says why in words instead of showing bare axes."""
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9)
    ax.set_yticks([])


def _left_out(missing: int, n: int) -> str:
    """The title's note of the recordings a panel has no value for."""
    return f"\n{missing} of {n} recordings without (not weighed)" if 0 < missing < n else ""


def residual_figure(data: ConveyorData) -> str | None:
    """Residual statistics of the constant-speed phases over time (std, kurtosis, crest)."""
    xs, label = _x(data)
    keys = (
        ("residual_std", "residual std [Nm]"),
        ("residual_kurtosis", "kurtosis [-]"),
        ("crest_factor", "crest factor [-]"),
    )
    series = []
    for key, ylabel in keys:
        pts = [
            (x, float(r["features"][key]))
            for x, r in zip(xs, data.results, strict=True)
            if (r.get("features") or {}).get(key) is not None
        ]
        series.append((key, ylabel, pts))
    if not any(pts for _k, _l, pts in series):
        return None
    fig = _figure(12.0, 3.2)
    for k, (_key, ylabel, pts) in enumerate(series):
        ax = fig.add_subplot(1, 3, k + 1)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", markersize=3, color="tab:blue")
        ax.set_ylabel(ylabel)
        _marks(ax, data)
        _time_axis(ax, label)
    fig.suptitle("residual of measured against model torque, constant-speed phases", fontsize=10)
    return _uri(fig)


def _spectra(
    recordings: Sequence[tuple[str, Recording]], kind: str
) -> tuple[list[str], list[Spectrum]]:
    labels, spectra = [], []
    for label, rec in recordings:
        try:
            sp = order_spectrum(rec) if kind == "order" else welch_spectrum(rec, average="median")
        except ChaintwinError:
            continue  # too short or too slow for a spectrum: left out of the waterfall
        labels.append(label)
        spectra.append(sp)
    return labels, spectra


def _waterfall_panel(
    ax: Axes, labels: list[str], spectra: list[Spectrum], lines: dict[str, float]
) -> None:
    top = min(float(sp.x[-1]) for sp in spectra)
    edges = np.linspace(0.0, top, GRID_POINTS + 1)
    grid = 0.5 * (edges[:-1] + edges[1:])
    image = np.vstack([np.interp(grid, sp.x, sp.amplitude) for sp in spectra])
    positive = image[image > 0]
    lo = float(np.percentile(positive, 5)) if positive.size else 1e-6
    hi = float(positive.max()) if positive.size else 1.0
    mesh = ax.pcolormesh(
        edges,
        np.arange(len(spectra) + 1) - 0.5,
        np.maximum(image, lo),
        norm=LogNorm(vmin=lo, vmax=max(hi, lo * 10)),
        cmap="viridis",
    )
    ax.figure.colorbar(mesh, ax=ax, label="torque amplitude [Nm]")
    step = max(1, len(labels) // 8)
    ax.set_yticks(range(0, len(labels), step))
    ax.set_yticklabels([labels[k][:16] for k in range(0, len(labels), step)], fontsize=7)
    for name, pos in lines.items():
        if 0 < pos < top:
            ax.axvline(pos, color="white", linewidth=0.6, linestyle="--", alpha=0.8)
            ax.text(pos, len(spectra) - 0.6, name, rotation=90, fontsize=6, color="white", va="top")


def _short(name: str) -> str:
    return (
        name.replace("sprocket_tooth_pass", "tooth pass")
        .replace("_rotation", "")
        .replace("_mesh", " mesh")
        .replace("_", " ")
    )


def _main(line: str) -> bool:
    """Not a harmonic (``..._h2``, ``..._h3``): marked lines stay readable."""
    return not line.endswith(("_h2", "_h3"))


def waterfall_figure(data: ConveyorData) -> str | None:
    """Order and frequency spectra of the torque over time (one row per recording)."""
    if not data.waterfall:
        return None
    labels_o, orders = _spectra(data.waterfall, "order")
    labels_f, freqs = _spectra(data.waterfall, "frequency")
    if not orders and not freqs:
        return None
    fig = _figure(12.0, 5.0)
    known = line_orders(data.profile)
    if orders:
        ts = float(np.median([rec.sample_time_s for _l, rec in data.waterfall]))
        rpm = float(np.median([sp.speed_rpm for sp in orders]))
        ax = fig.add_subplot(1, 2, 1)
        wanted = {_short(k): apparent_order(v, rpm, ts) for k, v in known.items() if _main(k)}
        _waterfall_panel(ax, labels_o, orders, wanted)
        ax.set_xlabel("order [1/motor revolution] (lines where they appear in the scope)")
        ax.set_title("order spectrum of the torque, per recording", fontsize=10)
    if freqs:
        ax = fig.add_subplot(1, 2, 2)
        rpm = float(np.median([sp.speed_rpm for sp in freqs]))
        ts = float(np.median([rec.sample_time_s for _l, rec in data.waterfall]))
        f_rot = rpm / 60.0
        wanted = {
            _short(k): apparent_order(v, rpm, ts) * f_rot for k, v in known.items() if _main(k)
        }
        _waterfall_panel(ax, labels_f, freqs, wanted)
        ax.set_xlabel("frequency [Hz] (constant-speed plateau, Welch, median of segments)")
        ax.set_title("torque spectrum at constant speed, per recording", fontsize=10)
    return _uri(fig)


CAMPBELL_PEAKS = 8
"""Strongest spectral peaks per recording drawn on the Campbell plot."""
CAMPBELL_PEAK_RATIO = 4.0
"""A peak is drawn when it stands this many times above the spectrum's median."""


def campbell_peaks(sp: Spectrum) -> tuple[FloatArray, FloatArray]:
    """The :data:`CAMPBELL_PEAKS` strongest local maxima standing out of the floor."""
    a = sp.amplitude
    if a.shape[0] < 3:
        return np.empty(0), np.empty(0)
    inner = (a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])
    idx = np.flatnonzero(inner) + 1
    idx = idx[a[idx] > CAMPBELL_PEAK_RATIO * float(np.median(a))]
    idx = idx[np.argsort(a[idx])[::-1][:CAMPBELL_PEAKS]]
    return sp.x[idx], a[idx]


def campbell_figure(data: ConveyorData) -> str | None:
    """Speed sweep (Campbell plot): the recordings' spectral peaks against their speed.

    x is the motor speed of each recording's constant-speed plateau (rpm), y
    the frequency (Hz); each recording's strongest peaks are dots sized and
    coloured by amplitude. The speed-locked lines are rays through the
    origin (frequency = order × speed), the structural modes horizontal
    lines (they do not move with speed); the scope's Nyquist frequency is
    marked, above which a line shows folded. A peak that follows a ray is
    the drive's; one that stays put while the speed changes is a structure's
    resonance. Recordings at one speed only give one column of dots.
    """
    if not data.waterfall:
        return None
    _labels, spectra = _spectra(data.waterfall, "frequency")
    if not spectra:
        return None
    ts = float(np.median([rec.sample_time_s for _l, rec in data.waterfall]))
    nyquist = 0.5 / ts
    speeds = np.array([abs(sp.speed_rpm) for sp in spectra])
    top_rpm = 1.15 * float(speeds.max())
    top_hz = min(nyquist, max(float(sp.x[-1]) for sp in spectra))
    fig = _figure(9.0, 5.5)
    ax = fig.add_subplot(1, 1, 1)
    rpm = np.array([0.0, top_rpm])
    lines = characteristic_lines(data.profile, float(np.median(speeds)), belt_modes=2)
    for line in lines:
        if line.order is not None and _main(line.name):
            f_top = line.order * top_rpm / 60.0
            ax.plot(rpm, rpm / 60.0 * line.order, color="0.55", linewidth=0.7)
            if 0 < f_top <= top_hz:
                ax.text(top_rpm, f_top, f" {_short(line.name)}", fontsize=6, va="center")
            elif f_top > top_hz and line.order > 0:
                x_at = 60.0 * top_hz / line.order
                ax.text(x_at, top_hz, _short(line.name), fontsize=6, rotation=60, va="bottom")
        elif line.order is None and 0 < line.frequency_hz < top_hz:
            ax.axhline(line.frequency_hz, color="tab:orange", linewidth=0.8, linestyle="--")
            ax.text(0.0, line.frequency_hz, f"{_short(line.name)} ", fontsize=6, ha="right")
    xs, ys, amps = [], [], []
    for sp, speed in zip(spectra, speeds, strict=True):
        f, a = campbell_peaks(sp)
        xs += [speed] * f.shape[0]
        ys += list(f)
        amps += list(a)
    if amps:
        amp = np.asarray(amps)
        size = 8.0 + 60.0 * amp / float(amp.max())
        dots = ax.scatter(xs, ys, s=size, c=amp, cmap="viridis", norm=LogNorm(), zorder=3)
        fig.colorbar(dots, ax=ax, label="torque amplitude [Nm]")
    ax.axhline(nyquist, color="tab:red", linewidth=0.8)
    ax.text(0.02 * top_rpm, nyquist, "Nyquist: lines above show folded", fontsize=7, va="bottom")
    ax.set_xlim(0.0, top_rpm)
    ax.set_ylim(0.0, 1.08 * nyquist)
    ax.set_xlabel("motor speed of the constant-speed plateau [rpm]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title(
        f"Campbell plot: peaks of {len(spectra)} recordings against their speed", fontsize=10
    )
    return _uri(fig)


def latest_figure(data: ConveyorData) -> str | None:
    """The latest recording: speed, torque against the calibrated model, and the residual."""
    rec = data.latest
    if rec is None:
        return None
    t = rec.time
    fig = _figure(12.0, 7.0)
    ax1 = fig.add_subplot(3, 1, 1)
    ax1.plot(t, rec.speed / RPM_TO_RAD_S, color="tab:blue", linewidth=0.9, label="speed")
    if rec.speed_setpoint is not None:
        ax1.plot(
            t,
            rec.speed_setpoint / RPM_TO_RAD_S,
            color="0.3",
            linewidth=0.8,
            linestyle="--",
            label="set point",
        )
    ax1.set_ylabel("motor speed [rpm]")
    ax1.legend(fontsize=7, loc="upper right")
    ax1.grid(True, alpha=0.3)
    ax2 = fig.add_subplot(3, 1, 2, sharex=ax1)
    ax2.plot(t, rec.torque, color="tab:blue", linewidth=0.8, label="measured")
    model = data.latest_model
    if model is not None:
        ax2.plot(t, model, color="tab:orange", linewidth=1.0, label="model (calibrated)")
    if rec.torque_setpoint is not None:
        ax2.plot(t, rec.torque_setpoint, color="0.5", linewidth=0.6, alpha=0.7, label="set point")
    ax2.set_ylabel("motor torque [Nm]")
    ax2.legend(fontsize=7, loc="upper right")
    ax2.grid(True, alpha=0.3)
    ax3 = fig.add_subplot(3, 1, 3, sharex=ax1)
    if model is not None:
        ax3.plot(t, rec.torque - model, color="tab:red", linewidth=0.7)
        ax3.set_ylabel("measured − model [Nm]")
    else:
        ax3.text(0.5, 0.5, "no calibration: no model", transform=ax3.transAxes, ha="center")
    ax3.set_xlabel("time since trigger [s]")
    ax3.grid(True, alpha=0.3)
    res = data.latest_result or {}
    pay = res.get("payload_kg")
    title = f"latest recording: {rec.source}"
    if isinstance(pay, int | float):
        title += f", payload {pay:.1f} kg"
    ax1.set_title(title, fontsize=10, parse_math=False)  # a file name may hold "$"
    return _uri(fig)


def fleet_health_figure(names: Sequence[str], index: Sequence[float]) -> str | None:
    """Health index per conveyor (0 baseline, 1 alarm limit)."""
    if not names:
        return None
    fig = _figure(8.0, 0.5 + 0.4 * len(names))
    ax = fig.add_subplot()
    vals = [0.0 if not math.isfinite(v) else v for v in index]
    colours = ["tab:red" if v >= 1 else "tab:orange" if v >= 0.7 else "tab:green" for v in vals]
    ax.barh(list(names), vals, color=colours)
    ax.axvline(1.0, color="tab:red", linestyle="--", linewidth=1.0)
    ax.invert_yaxis()
    ax.set_xlabel("health index: worst feature, 0 = baseline, 1 = alarm limit")
    ax.grid(True, axis="x", alpha=0.3)
    return _uri(fig)


def fleet_tlf_figure(names: Sequence[str], tlf: Sequence[float]) -> str | None:
    """Median TLF of the latest recordings per conveyor (those with one; None if none has)."""
    have = [(n, v) for n, v in zip(names, tlf, strict=True) if math.isfinite(v)]
    if not have:
        return None
    fig = _figure(8.0, 0.5 + 0.4 * len(have))
    ax = fig.add_subplot()
    ax.barh([n for n, _ in have], [v for _, v in have], color="tab:orange")
    ax.invert_yaxis()
    ax.set_xlabel("transport loss factor, median of the latest recordings [-]")
    ax.grid(True, axis="x", alpha=0.3)
    return _uri(fig)
