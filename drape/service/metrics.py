"""Prometheus metrics, one registry per app: requests, latencies, inference time, frames and vertices
served, and admission control (computing, queued, refused, cut)."""

from __future__ import annotations

import time

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drape.service.problems import METHODS


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter("drape_requests_total", "HTTP requests", ["route", "method", "status"],
                                registry=self.registry)
        self.latency = Histogram("drape_request_seconds", "HTTP request latency (to the answer's start)",
                                 ["route", "method"], registry=self.registry)
        self.inference = Histogram("drape_inference_seconds", "model inference time", ["stage"],
                                   registry=self.registry)
        self.frames = Counter("drape_frames_served_total", "posed frames served", registry=self.registry)
        self.vertices = Counter("drape_vertices_served_total", "posed vertices served (frames x N)",
                                registry=self.registry)
        self.active = Gauge("drape_inflight_requests", "heavy requests computing now", registry=self.registry)
        self.queued = Gauge("drape_queue_depth", "heavy requests waiting for a computing slot", registry=self.registry)
        self.rejected = Counter("drape_rejections_total", "heavy requests refused with a 503", ["reason"],
                                registry=self.registry)
        self.cut = Counter("drape_answers_cut_total", "answers stopped before their end", ["reason"],
                           registry=self.registry)

    def observe_inference(self, stage: str, seconds: float) -> None:
        self.inference.labels(stage=stage).observe(seconds)

    def admission(self, active: int, waiting: int) -> None:
        self.active.set(active)
        self.queued.set(waiting)

    def rejection(self, reason: str) -> None:
        self.rejected.labels(reason=reason).inc()

    def served(self, frames: int, num_vertices: int) -> None:
        self.frames.inc(frames)
        self.vertices.inc(frames * num_vertices)

    def render(self) -> bytes:
        return generate_latest(self.registry)




class CountRequests:
    """ASGI middleware: counts requests by route, method and status, and times them to the answer's start."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app, self.metrics = app, metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()

        async def counting_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                route = getattr(scope.get("route"), "path", "unmatched")
                method = scope.get("method", "")
                # any other method a client sends is "other": each made-up name was a series of its own, kept
                # for good (6,000 names made /metrics 10 MB, rendered on the event loop, with no key needed)
                method = method if method in METHODS else "other"
                self.metrics.requests.labels(route=route, method=method, status=str(message["status"])).inc()
                self.metrics.latency.labels(route=route, method=method).observe(time.perf_counter() - start)
            await send(message)

        await self.app(scope, receive, counting_send)

