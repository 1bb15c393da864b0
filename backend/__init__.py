"""Web and data side of handloop: FastAPI app, settings, database, services and the `handloop` CLI.

The API process does not import torch at start-up; compute lives in `workers`.
"""
