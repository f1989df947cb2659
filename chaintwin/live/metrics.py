"""The live service's Prometheus metrics (``GET /metrics``, text format).

=============================================  ===========================================
metric                                         what
=============================================  ===========================================
``chaintwin_recordings_ingested_total``        recordings stored (with their result, or
                                               waiting for a learned calibration), by
                                               source kind (``folder``, ``opcua``, ...)
``chaintwin_recordings_refused_total``         recordings refused, by source kind
``chaintwin_recordings_duplicate_total``       recordings whose content was stored already
``chaintwin_ingest_latency_seconds``           from a recording complete (a file settled,
                                               a scope read) to its result stored
``chaintwin_ingest_queue_depth``               recordings waiting to be ingested (the one
                                               in hand included)
``chaintwin_open_alarms``                      open alarms in the store
``chaintwin_conveyor_health``                  1 per conveyor with its verdict's ``health``
                                               and ``ne107`` as labels
``chaintwin_conveyor_health_index``            each conveyor's health index (0 baseline,
                                               1 alarm limit; left out while none)
``chaintwin_opcua_connections_up``             drives connected over OPC UA
``chaintwin_opcua_missed_scopes_total``        scopes the drives overwrote before they were
                                               read (counter gaps), by conveyor
``chaintwin_sources_held``                     sources this process follows (leases held)
``chaintwin_notifications_sent_total``         notifications delivered (2xx)
``chaintwin_notifications_failed_total``       delivery attempts that failed (retried)
``chaintwin_outbox_pending``                   notifications not yet delivered to every
                                               receiver
=============================================  ===========================================

The counters count what this process did since it started (Prometheus
takes restarts into account); the gauges are read when scraped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from chaintwin.store.schema import AlarmRow
from chaintwin.store.store import Store
from chaintwin.store.verdicts import VerdictCache

from .sources import DriveStatusLike

__all__ = ["CONTENT_TYPE", "LATENCY_BUCKETS_S", "Metrics"]

LATENCY_BUCKETS_S = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 30.0, 60.0)
"""Buckets of the ingest latency histogram, s."""

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
"""The Prometheus text format's media type."""


class _Scraped(Collector):
    """Gauges read when scraped: the store's open alarms, the conveyors' verdicts, the drives'
    connections."""

    def __init__(self, metrics: Metrics) -> None:
        self.metrics = metrics

    def collect(self) -> Iterator[GaugeMetricFamily | CounterMetricFamily]:
        m = self.metrics
        alarms = GaugeMetricFamily("chaintwin_open_alarms", "Open alarms in the store.")
        with Session(m.store.engine) as s:
            n = s.scalar(
                select(func.count()).select_from(AlarmRow).where(AlarmRow.status == "open")
            )
        alarms.add_metric([], float(n or 0))
        yield alarms
        health = GaugeMetricFamily(
            "chaintwin_conveyor_health",
            "Each conveyor's verdict: 1, with its health and NE 107 category as labels.",
            labels=["conveyor", "health", "ne107"],
        )
        index = GaugeMetricFamily(
            "chaintwin_conveyor_health_index",
            "Each conveyor's health index: 0 at its baseline, 1 at an alarm limit.",
            labels=["conveyor"],
        )
        for conveyor, v in sorted(m.verdicts.verdicts(m.store).items()):
            health.add_metric([conveyor, v.health, v.ne107], 1.0)
            if v.health_index is not None:
                index.add_metric([conveyor], v.health_index)
        yield health
        yield index
        up = GaugeMetricFamily("chaintwin_opcua_connections_up", "Drives connected over OPC UA.")
        missed = CounterMetricFamily(
            "chaintwin_opcua_missed_scopes",
            "Scopes the drives overwrote before they were read (counter gaps).",
            labels=["conveyor"],
        )
        drives = m.drive_status.drives if m.drive_status is not None else {}
        up.add_metric([], float(sum(1 for d in drives.values() if d.connected)))
        for conveyor, d in sorted(drives.items()):
            missed.add_metric([conveyor], float(d.missed))
        yield up
        yield missed
        if m.outbox_pending is not None:
            pending = GaugeMetricFamily(
                "chaintwin_outbox_pending",
                "Notifications not yet delivered to every receiver.",
            )
            pending.add_metric([], float(m.outbox_pending()))
            yield pending


class Metrics:
    """The metrics of one service process (a registry of its own).

    Parameters
    ----------
    store : Store
        Read for the open alarms when scraped.
    queue_depth : callable
        Recordings waiting to be ingested.
    """

    def __init__(self, store: Store, queue_depth: Callable[[], float]) -> None:
        self.store = store
        self.registry = CollectorRegistry()
        self.drive_status: DriveStatusLike | None = None
        self.outbox_pending: Callable[[], int] | None = None
        self.verdicts = VerdictCache()
        r = self.registry
        self.ingested = Counter(
            "chaintwin_recordings_ingested",
            "Recordings stored (with their result, or waiting for a calibration).",
            ["source"],
            registry=r,
        )
        self.refused = Counter(
            "chaintwin_recordings_refused", "Recordings refused.", ["source"], registry=r
        )
        self.duplicates = Counter(
            "chaintwin_recordings_duplicate",
            "Recordings whose content was stored already.",
            ["source"],
            registry=r,
        )
        self.latency = Histogram(
            "chaintwin_ingest_latency_seconds",
            "From a recording complete (file settled, scope read) to its result stored, s.",
            buckets=LATENCY_BUCKETS_S,
            registry=r,
        )
        self.queue = Gauge(
            "chaintwin_ingest_queue_depth", "Recordings waiting to be ingested.", registry=r
        )
        self.queue.set_function(queue_depth)
        self.held = Gauge(
            "chaintwin_sources_held", "Sources this process follows (leases held).", registry=r
        )
        self.sent = Counter(
            "chaintwin_notifications_sent", "Notifications delivered (2xx).", registry=r
        )
        self.failed = Counter(
            "chaintwin_notifications_failed",
            "Notification attempts that failed (retried with backoff).",
            registry=r,
        )
        r.register(_Scraped(self))

    def text(self) -> bytes:
        """The metrics in the Prometheus text format."""
        return generate_latest(self.registry)
