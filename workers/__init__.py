"""Compute side of handloop: the ML core (hand model, geometry, rendering, fitting, networks,
synthetic captures, evaluation) and the Celery tasks. Importable without a broker."""
