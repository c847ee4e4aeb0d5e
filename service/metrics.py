"""Prometheus metrics, kept by hand (a few counters and histograms need no library) and an
ASGI middleware that times every request (metrics live on the app's service) by route template (bounded label cardinality)."""
from __future__ import annotations

import time
from bisect import bisect_left
from collections import defaultdict
from typing import Any, Callable

LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)
WORK_BUCKETS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300)


class Histogram:
    def __init__(self, buckets):
        self.buckets = tuple(buckets)
        self.counts = [0] * (len(self.buckets) + 1)
        self.sum = 0.0
        self.count = 0

    def observe(self, value: float) -> None:
        self.counts[bisect_left(self.buckets, value)] += 1
        self.sum += value
        self.count += 1


class Metrics:
    def __init__(self):
        self.requests: dict[tuple, int] = defaultdict(int)         # (method, route, status)
        self.latency: dict[str, Histogram] = {}                     # route
        self.thumbnails: dict[str, int] = defaultdict(int)          # hit | miss | not_modified
        self.render = Histogram(WORK_BUCKETS)
        self.bake = Histogram(WORK_BUCKETS)
        self.bake_results: dict[str, int] = defaultdict(int)        # ready | failed
        self.restarts: dict[str, int] = defaultdict(int)            # crash | deadline
        self.rejected: dict[str, int] = defaultdict(int)            # queue_full | too_large
        self.gauges: dict[str, tuple[str, Callable[[], dict[str, Any]]]] = {}  # name -> () -> {labels: value}

    def observe_request(self, method: str, route: str, status: int, seconds: float) -> None:
        self.requests[(method, route, status)] += 1
        hist = self.latency.get(route)
        if hist is None:
            hist = self.latency[route] = Histogram(LATENCY_BUCKETS)
        hist.observe(seconds)

    def render_text(self) -> str:
        out: list[str] = []
        _counter(out, "asset_preview_http_requests_total", "HTTP requests answered",
                 {f'method="{m}",route="{r}",status="{s}"': v for (m, r, s), v in self.requests.items()})
        out += ["# HELP asset_preview_http_request_duration_seconds Time to answer a request",
                "# TYPE asset_preview_http_request_duration_seconds histogram"]
        for route, hist in self.latency.items():
            _histogram(out, "asset_preview_http_request_duration_seconds", hist, f'route="{route}"')
        _counter(out, "asset_preview_thumbnail_cache_total", "Thumbnail requests by cache outcome",
                 {f'result="{k}"': v for k, v in self.thumbnails.items()})
        for name, hist, text in (("render", self.render, "Render time in a worker"),
                                 ("bake", self.bake, "Bake time in a worker")):
            out += [f"# HELP asset_preview_{name}_seconds {text}",
                    f"# TYPE asset_preview_{name}_seconds histogram"]
            _histogram(out, f"asset_preview_{name}_seconds", hist, "")
        _counter(out, "asset_preview_bakes_total", "Finished bakes by result",
                 {f'result="{k}"': v for k, v in self.bake_results.items()})
        _counter(out, "asset_preview_worker_restarts_total", "Render workers replaced",
                 {f'reason="{k}"': v for k, v in self.restarts.items()})
        _counter(out, "asset_preview_rejected_total", "Requests refused for capacity",
                 {f'reason="{k}"': v for k, v in self.rejected.items()})
        for name, (help_text, read) in self.gauges.items():
            out += [f"# HELP {name} {help_text}", f"# TYPE {name} gauge"]
            for labels, value in read().items():
                out.append(f"{name}{{{labels}}} {value}" if labels else f"{name} {value}")
        return "\n".join(out) + "\n"


def _counter(out: list[str], name: str, help_text: str, series: dict[str, int]) -> None:
    out += [f"# HELP {name} {help_text}", f"# TYPE {name} counter"]
    out += [f"{name}{{{labels}}} {value}" for labels, value in series.items()]


def _histogram(out: list[str], name: str, hist: Histogram, labels: str) -> None:
    sep = "," if labels else ""
    running = 0
    for bound, count in zip(hist.buckets, hist.counts):
        running += count
        out.append(f'{name}_bucket{{{labels}{sep}le="{bound:g}"}} {running}')
    out.append(f'{name}_bucket{{{labels}{sep}le="+Inf"}} {hist.count}')
    braces = f"{{{labels}}}" if labels else ""
    out.append(f"{name}_sum{braces} {hist.sum:.6f}")
    out.append(f"{name}_count{braces} {hist.count}")


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
