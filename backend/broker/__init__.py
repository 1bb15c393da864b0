"""The job hand-off's broker plumbing: Celery's configuration and client (celery_queue), the embedded
filesystem broker (embedded, claims) and the outbox that sends again what never reached a worker (outbox).
Below the domain services: it knows job rows, never routes or services (docs/architecture.md)."""
