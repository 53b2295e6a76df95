"""``GET /metrics``: the station's figures in the Prometheus text format.

Optionally behind a bearer token (``blackbox station --metrics-token-env NAME``), never
behind the page's session: scrapers have no cookies. Names follow the Prometheus
conventions (``blackbox_station_`` prefix, ``_total`` counters, base units).
"""

from __future__ import annotations

import hmac
import time

from fastapi import APIRouter, Request
from fastapi.responses import Response

from blackbox.prometheus import CONTENT_TYPE, MetricsText
from blackbox.station.alerts.service import AlertService
from blackbox.station.delivery import DeliveryWatch
from blackbox.station.store import EVENT_KINDS, STATUSES, StationStore


def station_metrics(store: StationStore, alerts: AlertService | None,
                    delivery: DeliveryWatch | None = None) -> str:
    out = MetricsText()
    fleet = store.fleet()
    out.family("blackbox_station_robots", "gauge", "Robots by the status shown to operators")
    for status in STATUSES:
        out.sample("blackbox_station_robots", sum(1 for r in fleet if r.status == status),
                   {"status": status})
    out.add("blackbox_station_robots_silent", "gauge", "Robots not heard for stale_after",
            sum(1 for r in fleet if r.stale))
    out.add("blackbox_station_unacknowledged_events", "gauge",
            "Failures and exceedances nobody acknowledged", sum(r.unacknowledged for r in fleet))
    out.family("blackbox_station_events_total", "counter", "Events stored, by kind")
    for kind in EVENT_KINDS:
        out.sample("blackbox_station_events_total", store.count_events(kinds=[kind]),
                   {"kind": kind})
    out.add("blackbox_station_store_commits_total", "counter",
            "Committed writes of the station database (the ingest rate is its rate())",
            store.sequence)
    out.add("blackbox_station_store_pending_writes", "gauge",
            "Changes heard but not yet committed (the ingest lag)", store.pending)
    heard = [r.last_heard for r in fleet if r.last_heard is not None and not r.stale]
    out.add("blackbox_station_ingest_age_seconds", "gauge",
            "Seconds since the most recent sample of any live robot",
            time.time() - max(heard) if heard else 0.0)
    out.add("blackbox_station_store_dropped_points_total", "counter",
            "Chart points dropped while the database could not be written",
            store.dropped_points)
    times = store.flush_times
    out.add("blackbox_station_store_commit_lag_seconds", "gauge",
            "Seconds the oldest change of the last committed batch waited to be committed",
            times.lag)
    out.add("blackbox_station_store_commit_lag_max_seconds", "gauge",
            "The largest commit lag since the station started", times.lag_max)
    out.add("blackbox_station_store_flush_seconds", "gauge",
            "Seconds the last committed flush spent writing", times.seconds)
    out.add("blackbox_station_store_flush_rows", "gauge",
            "Changes the last committed flush wrote", times.rows)
    out.add("blackbox_station_store_coalesced_points_total", "counter",
            "Chart points replaced by a newer one of their characteristic while the write "
            "queue was full", store.coalesced_points)
    out.add("blackbox_station_store_dropped_changes_total", "counter",
            "Changes other than chart points dropped while the write queue stayed full",
            store.dropped_changes)
    out.add("blackbox_station_problems", "gauge", "Problems shown on the page",
            len(store.problems(200)))
    if delivery is not None:
        out.add("blackbox_station_samples_dropped_total", "counter",
                "Samples the bus dropped before the station took them (DDS sample lost or "
                "rejected, Zenoh queue full)", delivery.counts.total())
        out.add("blackbox_station_ingest_behind", "gauge",
                "1 while the station cannot keep up with the fleet", int(delivery.behind))
        out.add("blackbox_station_ingest_behind_seconds_total", "counter",
                "Seconds the station spent with samples waiting", delivery.behind_total)
        out.add("blackbox_station_values_coalesced_total", "counter",
                "Characteristic values left out while the station was behind, each for a "
                "newer value of its characteristic", delivery.coalesced)
    if alerts is not None:
        engine = alerts.engine
        out.family("blackbox_station_alerts", "gauge", "Alerts by state")
        states: dict[str, int] = {}
        for (_, state), n in engine.counts().items():
            states[state] = states.get(state, 0) + n
        for state in ("pending", "firing", "acknowledged", "resolved"):
            out.sample("blackbox_station_alerts", states.get(state, 0), {"state": state})
        out.add("blackbox_station_alerts_unacknowledged", "gauge",
                "Fired alerts nobody acknowledged", states.get("firing", 0))
        out.family("blackbox_station_notifications_total", "counter",
                   "Notifications by channel and outcome (pending: not delivered yet)")
        for (channel, state), n in sorted(alerts.outbox.counts().items()):
            out.sample("blackbox_station_notifications_total", n,
                       {"channel": channel, "outcome": state})
        out.family("blackbox_station_unmatched_events_total", "counter",
                   "Events no alert rule matched (kept 7 days)")
        for kind, n in sorted(engine.unmatched_total().items()):
            out.sample("blackbox_station_unmatched_events_total", n, {"kind": kind})
        out.add("blackbox_station_database_bytes", "gauge", "Size of the station database",
                alerts.db.size_bytes())
    return out.render()


def metrics_router(store: StationStore, alerts: AlertService | None,
                   token: str | None, delivery: DeliveryWatch | None = None) -> APIRouter:
    router = APIRouter()

    @router.get("/metrics", include_in_schema=False)
    async def metrics(request: Request) -> Response:
        if token:
            presented = request.headers.get("authorization", "")
            if not hmac.compare_digest(presented.encode(), f"Bearer {token}".encode()):
                return Response("metrics need the bearer token\n", status_code=401,
                                media_type="text/plain",
                                headers={"WWW-Authenticate": "Bearer"})
        return Response(station_metrics(store, alerts, delivery), media_type=CONTENT_TYPE)

    return router
