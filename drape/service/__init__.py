"""The FastAPI service: routers, handlers, settings."""
