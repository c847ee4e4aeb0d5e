"""Prometheus metrics (prometheus-client, one registry per service: label values escaped by
the library) and an ASGI middleware that times every request by route template (bounded label
cardinality)."""
from __future__ import annotations

import time
from typing import Any, Callable

from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily

LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)
WORK_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300)
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


class Metrics:
    def __init__(self):
        self.registry = r = CollectorRegistry(auto_describe=True)
        self.requests = Counter("asset_preview_http_requests", "HTTP requests answered",
                                ["method", "route", "status"], registry=r)
        self.latency = Histogram("asset_preview_http_request_duration_seconds", "Time to answer a request",
                                 ["route"], buckets=LATENCY_BUCKETS, registry=r)
        self.thumbnails = Counter("asset_preview_thumbnail_cache", "Thumbnail requests by cache outcome",
                                  ["result"], registry=r)  # hit | miss | not_modified
        self.render = Histogram("asset_preview_render_seconds", "Render time in a worker",
                                buckets=WORK_BUCKETS, registry=r)
        self.bake = Histogram("asset_preview_bake_seconds", "Bake time in a worker",
                              buckets=WORK_BUCKETS, registry=r)
        self.bake_results = Counter("asset_preview_bakes", "Finished bakes by result", ["result"], registry=r)
        self.restarts = Counter("asset_preview_worker_restarts", "Render workers replaced", ["reason"], registry=r)
        self.rejected = Counter("asset_preview_rejected", "Requests refused for capacity or cost",
                                ["reason"], registry=r)  # queue_full | too_large | over_cost
        self._children: dict[tuple, tuple] = {}
        self._thumbnail_children: dict[str, Any] = {}
        self._gauges = _Gauges()
        r.register(self._gauges)

    def gauge(self, name: str, help_text: str, labels: tuple[str, ...], read: Callable[[], dict]) -> None:
        """A gauge read when scraped: `read()` -> {label values tuple: value}."""
        self._gauges.add(name, help_text, labels, read)

    def observe_request(self, method: str, route: str, status: int, seconds: float) -> None:
        # The labelled children, looked up once per label set: `labels()` costs ~4 us a call,
        # which the hot path (a cached thumbnail, well under a millisecond) notices.
        key = (method, route, status)
        child = self._children.get(key)
        if child is None:
            child = self._children[key] = (self.requests.labels(method, route, str(status)),
                                           self.latency.labels(route))
        child[0].inc()
        child[1].observe(seconds)

    def thumbnail(self, outcome: str) -> None:
        child = self._thumbnail_children.get(outcome)
        if child is None:
            child = self._thumbnail_children[outcome] = self.thumbnails.labels(outcome)
        child.inc()

    def render_text(self) -> bytes:
        return generate_latest(self.registry)


class _Gauges:
    def __init__(self):
        self._items: list[tuple[str, str, tuple[str, ...], Callable[[], dict]]] = []

    def add(self, name, help_text, labels, read) -> None:
        self._items.append((name, help_text, labels, read))

    def describe(self):
        return []

    def collect(self):
        for name, help_text, labels, read in self._items:
            family = GaugeMetricFamily(name, help_text, labels=list(labels))
            for values, value in read().items():
                family.add_metric(list(values), value)
            yield family


class MetricsMiddleware:
    """Pure ASGI (no per-request task or body copy, unlike BaseHTTPMiddleware): records
    method, route template and status of every HTTP request."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        start = time.perf_counter()
        status = 500

        async def send_wrapper(message):
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            route = scope.get("route")
            scope["app"].state.service.metrics.observe_request(scope["method"], getattr(route, "path", "unmatched"),
                                                               status, time.perf_counter() - start)
