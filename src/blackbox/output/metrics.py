"""``blackbox run --metrics HOST:PORT``: the black box's own figures for the robot's own
monitoring (Prometheus text format at ``/metrics``).

A sink keeps the latest verdict of every observed characteristic; the pipeline's counters
and the recorder's queue come from the running objects when scraped. The server is a
small standard-library HTTP server on its own thread: the robot computer should not need a
web framework for one page.
"""

from __future__ import annotations

import http.server
import threading
from collections.abc import Sequence
from typing import Any

from blackbox.model import Observation, Resource
from blackbox.pipeline import Pipeline
from blackbox.prometheus import CONTENT_TYPE, MetricsText
from blackbox.sinks import SinkBase


class RobotMetrics(SinkBase):
    """Latest state of each (observer, resource), and the pipeline's counters."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._faulty: dict[tuple[str, Resource], bool] = {}
        self.pipeline: Pipeline | None = None

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self._lock:
            for obs in observations:
                self._faulty[obs.key()] = obs.faulty

    def render(self) -> str:
        out = MetricsText()
        with self._lock:
            faulty = sum(self._faulty.values())
            total = len(self._faulty)
        out.family("blackbox_observers", "gauge",
                   "Observed characteristics by the state of their latest verdict")
        out.sample("blackbox_observers", total - faulty, {"state": "ok"})
        out.sample("blackbox_observers", faulty, {"state": "faulty"})
        pipeline = self.pipeline
        if pipeline is not None:
            stats = pipeline.stats
            out.add("blackbox_messages_received_total", "counter",
                    "Messages received from the robot", stats.messages)
            out.add("blackbox_observations_total", "counter", "Verdicts made",
                    stats.observations)
            out.add("blackbox_faulty_observations_total", "counter", "Faulty verdicts",
                    stats.faulty_observations)
            out.add("blackbox_diagnoses_total", "counter", "Diagnoses made", stats.diagnoses)
            out.add("blackbox_internal_errors_total", "counter",
                    "Errors of observers and sinks (caught, counted)", stats.errors)
            recorder: Any = next((s for s in pipeline.sinks if hasattr(s, "pending")
                                  and hasattr(s, "dropped")), None)
            if recorder is not None:
                out.add("blackbox_recorder_queued_rows", "gauge",
                        "Rows waiting to be written to the health log (the recorder's lag)",
                        recorder.pending)
                out.add("blackbox_recorder_dropped_rows_total", "counter",
                        "Rows the recorder had to drop", recorder.dropped)
                out.add("blackbox_recorder_written_rows_total", "counter",
                        "Rows written to the health log", recorder.written)
        return out.render()


class MetricsServer:
    """``GET /metrics`` on ``host:port`` (port 0: any free one; see :attr:`port`)."""

    def __init__(self, metrics: RobotMetrics, host: str, port: int) -> None:
        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                if self.path.split("?")[0] != "/metrics":
                    self.send_error(404, "only /metrics here")
                    return
                body = metrics.render().encode()
                self.send_response(200)
                self.send_header("Content-Type", CONTENT_TYPE)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                return None

        self._server = http.server.ThreadingHTTPServer((host, port), Handler)
        self._server.daemon_threads = True
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True,
                                        name="metrics")

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._server.shutdown()
        self._server.server_close()
