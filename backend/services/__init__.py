"""Domain logic. Services raise `backend.services.errors.DomainError`s; only the API edge maps them to
HTTP responses."""
