"""The spectrum waterfall of a conveyor's latest recordings, for the dashboard.

The store keeps each recording's samples, not its spectra: the waterfall is
computed from the samples of the latest ``count`` monitored recordings (the
torque's order spectrum, or its Welch spectrum at constant speed), each
downsampled to :data:`POINTS` bins of one common axis by the largest
amplitude in each bin (a line stays as high as it is, however narrow). A
recording's spectrum never changes, so it is computed once per process
(:class:`SpectrumCache`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, Literal

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from chaintwin.diagnose.spectra import Spectrum, order_spectrum, welch_spectrum
from chaintwin.errors import ChaintwinError
from chaintwin.model.frequencies import apparent_order, line_orders
from chaintwin.store.schema import RecordingRow
from chaintwin.store.store import Store

__all__ = ["POINTS", "SpectrumCache", "waterfall"]

POINTS = 400
"""Bins of the common axis each spectrum is downsampled onto."""

Kind = Literal["order", "frequency"]


class SpectrumCache:
    """Spectra of stored recordings by (recording id, kind), the latest ``size`` kept.

    A recording whose spectrum cannot be computed (too short, too slow) is
    kept as None, so that it is not tried again.
    """

    def __init__(self, size: int = 2000) -> None:
        self.size = size
        self._items: OrderedDict[tuple[int, str], tuple[Spectrum, float] | None] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, store: Store, recording_id: int, kind: Kind) -> tuple[Spectrum, float] | None:
        """The spectrum of a stored recording's torque and its sample time, s (None: none)."""
        key = (recording_id, kind)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        rec = store.recording(recording_id)
        try:
            sp: tuple[Spectrum, float] | None = (
                order_spectrum(rec) if kind == "order" else welch_spectrum(rec, average="median"),
                rec.sample_time_s,
            )
        except ChaintwinError:
            sp = None
        with self._lock:
            self._items[key] = sp
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return sp


def _bin_max(sp: Spectrum, edges: np.ndarray) -> list[float | None]:
    """The largest amplitude in each bin (None for a bin holding no point), Nm."""
    x, a = np.asarray(sp.x), np.asarray(sp.amplitude)
    n = edges.shape[0] - 1
    idx = np.searchsorted(edges, x, side="right") - 1
    idx[x == edges[-1]] = n - 1  # the upper edge belongs to the last bin
    ok = (idx >= 0) & (idx < n)
    out = np.full(n, -np.inf)
    np.maximum.at(out, idx[ok], a[ok])
    return [float(v) if np.isfinite(v) else None for v in out]


def waterfall(
    store: Store, conveyor: str, cache: SpectrumCache, *, kind: Kind = "order", count: int = 20
) -> dict[str, Any]:
    """The torque spectra of a conveyor's latest ``count`` recordings on one axis.

    Parameters
    ----------
    store : Store
        The results store.
    conveyor : str
        Conveyor id (known to the store).
    cache : SpectrumCache
        The process's spectra.
    kind : {"order", "frequency"}
        Order spectrum (per motor revolution) or Welch spectrum at constant speed, Hz.
    count : int
        Most recordings, the latest.

    Returns
    -------
    dict
        ``kind``, ``x_unit``, ``x`` (bin centres), ``recordings`` (oldest
        first: ``recording_id``, ``file``, ``recorded_at``), ``amplitude_nm``
        (one row per recording, None for an empty bin), ``lines`` (where the
        profile's speed-locked lines appear, folded as in the scope), and
        ``left_out`` (files with no spectrum: too short or too slow).
    """
    index = store.recording_index(conveyor)[-count:]
    with Session(store.engine) as s:
        shas = dict(
            s.execute(
                select(RecordingRow.id, RecordingRow.sha256).where(
                    RecordingRow.id.in_([rid for rid, _f, _a in index])
                )
            ).all()
        )
    rows: list[tuple[dict[str, Any], Spectrum]] = []
    left_out: list[str] = []
    times: list[float] = []
    for rid, name, at in index:
        got = cache.get(store, rid, kind)
        if got is None:
            left_out.append(name)
            continue
        rows.append(({"recording_id": shas.get(rid), "file": name, "recorded_at": at}, got[0]))
        times.append(got[1])
    out: dict[str, Any] = {
        "conveyor": conveyor,
        "kind": kind,
        "x_unit": "order (1/motor revolution)" if kind == "order" else "Hz",
        "x": [],
        "recordings": [r for r, _sp in rows],
        "amplitude_nm": [],
        "lines": {},
        "left_out": left_out,
    }
    if not rows:
        return out
    top = min(float(sp.x[-1]) for _r, sp in rows)
    edges = np.linspace(0.0, top, POINTS + 1)
    out["x"] = [float(v) for v in 0.5 * (edges[:-1] + edges[1:])]
    out["amplitude_nm"] = [_bin_max(sp, edges) for _r, sp in rows]
    profile = store.profile(conveyor)
    if profile is not None:
        rpm = float(np.median([sp.speed_rpm for _r, sp in rows]))
        ts = float(np.median(times))
        if ts > 0.0 and rpm > 0.0:
            f_rot = rpm / 60.0
            for name, order in line_orders(profile).items():
                if name.endswith(("_h2", "_h3")):
                    continue  # harmonics: the marks stay readable
                pos = apparent_order(order, rpm, ts) * (1.0 if kind == "order" else f_rot)
                if 0.0 < pos < top:
                    out["lines"][name] = pos
    return out
