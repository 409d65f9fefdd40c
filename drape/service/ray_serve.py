"""Scale-out on Ray Serve: the same FastAPI app (`create_app`) as a Serve ingress deployment, N replicas on an
existing Ray cluster behind Serve's HTTP proxies (`drape serve --ray ADDRESS --replicas N`, or
`serve run deploy/serve.yaml`).

Each replica is its own Ray actor (a process) that builds the app with `create_app(settings)`; Serve runs the
app's lifespan in the replica (Ray 2.60 does, for ingress deployments), so every replica loads and warms its own
engine before it takes traffic, and stops it on shutdown. The app's admission control and limits therefore apply
per replica: the cluster computes up to replicas x max_active heavy requests at once.

Rigs are shared between replicas: an app-wide `OutfitStore` deployment (one replica, no CPU) keeps the rigged
outfits by outfit_id (the content hash of mesh + body + model, so a rig is the same whichever replica made it).
A replica that misses an outfit_id in its own cache asks the store before answering 404, and a replica asked to
rig a mesh another replica already rigged takes the stored rig. So an outfit_id from a rig answer works on every
replica, until the store's LRU (`outfit_cache_bytes`) drops it: then the 404 says "rig the outfit again", as on
a single server, and rigging the same mesh again gives the same outfit_id.

Ray is imported lazily: the serving path without the `cluster` extra never imports it.
"""

from __future__ import annotations

import copy
import functools
import logging
import signal
import sys
import time
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING, Any

import numpy as np
from fastapi import FastAPI

from drape.runtime.cache import LRUBytesCache
from drape.runtime.engine import Engine, RiggedOutfit
from drape.service.app import create_app
from drape.service.settings import Settings

if TYPE_CHECKING:
    from ray.serve import Application
    from ray.serve.handle import DeploymentHandle

log = logging.getLogger(__name__)

APP_NAME = "drape"
REPLICA_HEADER = "x-drape-replica"  # which replica answered (its Serve replica id; no pid, no host)
STORE_TIMEOUT_S = 30.0
LIGHT_REQUESTS = 32  # Serve lets a replica hold max_active + max_queue heavy requests plus this many others


def replica_settings(settings: Settings) -> Settings:
    """The settings a replica runs with: refinement in the replica's own process (refine_workers=1) unless
    refine_workers was given (argument or DRAPE_REFINE_WORKERS), so N replicas do not start N process pools."""
    if "refine_workers" in settings.model_fields_set:
        return settings
    return settings.model_copy(update={"refine_workers": 1})


class OutfitStore:
    """The rigged outfits of all replicas, by outfit_id, most recently used kept within `max_bytes`."""

    def __init__(self, max_bytes: int) -> None:
        self.cache: LRUBytesCache[RiggedOutfit] = LRUBytesCache(max_bytes)

    async def get(self, outfit_id: str) -> RiggedOutfit | None:
        return self.cache.get(outfit_id)

    async def put(self, outfit: RiggedOutfit) -> None:
        self.cache.put(outfit.outfit_id, outfit)


class SharedOutfitEngine(Engine):
    """The replica's engine (same model, cache and refinement pool), with the outfit store behind its cache.
    rig and lookup run in the thread pool (never on the event loop), so they may wait for the store."""

    def __init__(self, engine: Engine, store: DeploymentHandle, timeout_s: float = STORE_TIMEOUT_S) -> None:
        self.__dict__.update(engine.__dict__)  # adopt the loaded engine; no second model load
        self._store = store
        self._timeout_s = timeout_s

    def lookup(self, outfit_id: str) -> RiggedOutfit | None:
        """The local cache, else the store's copy (kept locally); None as Engine.lookup, also while the
        outfit's body is not held on this replica (a user body deleted or never registered here)."""
        if self.cache.get(outfit_id) is None:
            outfit = self._fetch(outfit_id)
            if outfit is not None:
                self.cache.put(outfit_id, outfit)
        return super().lookup(outfit_id)

    def rig(self, vertices: np.ndarray, faces: np.ndarray, body: str, influences: int = 4,
            uv_corners: np.ndarray | None = None) -> RiggedOutfit:
        known = self.lookup(self.outfit_id(vertices, faces, body, influences, uv_corners))
        if known is not None:
            return known
        outfit = super().rig(vertices, faces, body, influences, uv_corners=uv_corners)
        try:  # waited for: once the rig is answered, its outfit_id works on every replica
            self._store.put.remote(outfit).result(timeout_s=self._timeout_s)
        except Exception:  # the store down or slow: this replica still has the rig
            log.warning("could not share outfit %s with the other replicas", outfit.outfit_id, exc_info=True)
        return outfit

    def _fetch(self, outfit_id: str) -> RiggedOutfit | None:
        try:
            shared = self._store.get.remote(outfit_id).result(timeout_s=self._timeout_s)
        except Exception:
            log.warning("outfit store unavailable; outfit_id %s looked up locally only", outfit_id, exc_info=True)
            return None
        # own, writable arrays: the ones Ray hands over are read-only views that pin the object store
        return None if shared is None else copy.deepcopy(shared)


class ServeAnswers:
    """ASGI middleware between the app and Serve: every answer says which replica gave it (x-drape-replica),
    and body pieces go out as bytes. The app streams memoryviews of its frame arrays (uvicorn writes them
    as they are); Serve pickles each ASGI message to the proxy, and a memoryview does not pickle."""

    def __init__(self, app: Any, replica: str) -> None:
        self.app, self.value = app, replica.encode()

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def to_serve(message: Any) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), (REPLICA_HEADER.encode(), self.value)]
            elif message["type"] == "http.response.body" and not isinstance(message.get("body", b""), bytes):
                message["body"] = bytes(message["body"])
            await send(message)

        await self.app(scope, receive, to_serve)


class DrapeReplica:
    """One Serve replica: its own app from `create_app(settings)`, built at replica start-up; Serve then runs
    the app's lifespan (engine loaded and warmed) before the replica takes requests."""

    def __init__(self, settings: Settings, store: DeploymentHandle | None = None) -> None:
        self.settings = settings
        self.store = store

    def __serve_build_asgi_app__(self) -> FastAPI:
        from ray import serve

        app = create_app(self.settings)
        store, inner = self.store, app.router.lifespan_context

        @asynccontextmanager
        async def lifespan(a: FastAPI) -> AsyncIterator[Any]:
            async with inner(a) as state:  # the app's own start-up: engine loaded, warmed; admission
                if store is not None:
                    a.state.engine = SharedOutfitEngine(a.state.engine, store)
                yield state

        app.router.lifespan_context = lifespan
        app.add_middleware(ServeAnswers, replica=serve.get_replica_context().replica_id.unique_id)
        return app


@functools.cache
def _deployments() -> tuple[Any, Any]:
    """The Serve deployments (made on first use: importing this module does not import ray)."""
    from ray import serve

    replica = serve.deployment(serve.ingress()(DrapeReplica), name="drape")
    store = serve.deployment(OutfitStore, name="outfit-store", num_replicas=1, max_ongoing_requests=1000,
                             ray_actor_options={"num_cpus": 0})
    return replica, store


def application(settings: Settings, replicas: int = 1, replica_cpus: float = 1.0,
                share_outfits: bool = True) -> Application:
    """The Serve application: `replicas` copies of the app (each `replica_cpus` CPUs) and the outfit store."""
    if replicas < 1:
        raise ValueError(f"replicas must be >= 1, not {replicas}")
    settings = replica_settings(settings)
    replica, store = _deployments()
    replica = replica.options(
        num_replicas=replicas,
        ray_actor_options={"num_cpus": replica_cpus},
        # Serve queues in front of a replica past this; let the app's own admission answer 503 instead
        max_ongoing_requests=settings.max_active + settings.max_queue + LIGHT_REQUESTS,
        graceful_shutdown_timeout_s=settings.shutdown_grace_s,
    )
    return replica.bind(settings, store.bind(settings.outfit_cache_bytes) if share_outfits else None)


def app(args: Mapping[str, Any]) -> Application:
    """Application builder for `serve run` / `serve deploy` (import_path: drape.service.ray_serve:app).

    args: `replicas` (default 1), `replica_cpus` (default 1) and any Settings field (model_dir, max_active,
    api_key, ...); the rest comes from the DRAPE_* environment (set it in the config's runtime_env.env_vars).
    Host and port are the config's http_options, not settings."""
    fields = dict(args)
    replicas = int(fields.pop("replicas", 1))
    replica_cpus = float(fields.pop("replica_cpus", 1.0))
    return application(Settings(**fields), replicas, replica_cpus)


def deploy(address: str, replicas: int, settings: Settings, *, replica_cpus: float = 1.0,
           name: str = APP_NAME, blocking: bool = True) -> DeploymentHandle:
    """Connect to the Ray cluster at `address` ("auto": the cluster this node belongs to; or the head's
    "host:6379"), unless this process is connected already; start Serve's HTTP proxies on settings.host:port
    (if Serve already runs on the cluster, its proxies keep their options) and deploy `replicas` replicas at "/".
    A cluster with token authentication (Ray 2.60's default for new clusters) needs its token here, and with an
    explicit address RAY_AUTH_MODE=token as well.

    blocking: serve until SIGINT/SIGTERM, then delete the application (Serve and the cluster keep running).
    Otherwise return the handle of the running application (tests)."""
    import ray
    from ray import serve

    if not ray.is_initialized():
        ray.init(address=address)
    serve.start(http_options={"host": settings.host, "port": settings.port,
                              "keep_alive_timeout_s": settings.timeout_keep_alive_s})
    handle = serve.run(application(settings, replicas, replica_cpus), name=name, route_prefix="/")
    if not blocking:
        return handle
    print(f"drape: {replicas} replica(s) serving on http://{settings.host}:{settings.port} "
          f"(Serve application {name!r}); Ctrl-C to stop", file=sys.stderr)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        while True:
            time.sleep(3600)
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        serve.delete(name)
    return handle


__all__ = ["APP_NAME", "REPLICA_HEADER", "DrapeReplica", "OutfitStore", "SharedOutfitEngine", "app",
           "application", "deploy", "replica_settings"]
