# drape service image: ONNX Runtime serving, no torch.
#   docker build -t drape .
#   docker run --rm --stop-timeout 30 -p 8000:8000 drape   # settings by DRAPE_* environment variables;
#   --stop-timeout 30: `docker stop` waits 10 s by default, less than DRAPE_SHUTDOWN_GRACE_S (20 s)
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /app

# only the [serve] extra: fastapi, uvicorn, onnxruntime, trimesh, scipy, pykdtree (the shipped models live in drape/assets)
COPY pyproject.toml README.md ./
COPY drape ./drape
RUN pip install ".[serve]" && useradd --create-home --uid 10001 drape

USER drape
ENV DRAPE_HOST=0.0.0.0 DRAPE_PORT=8000
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
  CMD python -c "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('DRAPE_PORT', '8000'), timeout=4)"
CMD ["drape", "serve"]
