# Image for docker-compose.yml: handloop with the CPU build of PyTorch pinned in pyproject.toml.
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends libgl1 libglib2.0-0 && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml README.md ./
COPY backend backend
COPY workers workers
COPY migrations migrations
COPY alembic.ini .
RUN pip install --no-cache-dir .
EXPOSE 8000
CMD ["handloop", "serve", "--host", "0.0.0.0"]
