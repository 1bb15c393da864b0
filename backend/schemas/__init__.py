"""Pydantic request and response models; every number has limits (finite, ranges)."""
