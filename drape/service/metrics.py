"""Prometheus metrics, one registry per app: requests, latencies, inference time, frames and vertices served."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter("drape_requests_total", "HTTP requests", ["route", "method", "status"],
                                registry=self.registry)
        self.latency = Histogram("drape_request_seconds", "HTTP request latency", ["route", "method"],
                                 registry=self.registry)
        self.inference = Histogram("drape_inference_seconds", "model inference time", ["stage"],
                                   registry=self.registry)
        self.frames = Counter("drape_frames_served_total", "posed frames served", registry=self.registry)
        self.vertices = Counter("drape_vertices_served_total", "posed vertices served (frames x N)",
                                registry=self.registry)

    def observe_inference(self, stage: str, seconds: float) -> None:
        self.inference.labels(stage=stage).observe(seconds)

    def served(self, frames: int, num_vertices: int) -> None:
        self.frames.inc(frames)
        self.vertices.inc(frames * num_vertices)

    def render(self) -> bytes:
        return generate_latest(self.registry)
