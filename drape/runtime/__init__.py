"""ONNX Runtime sessions, model registry and batching (no torch). Filled by the service issue."""
