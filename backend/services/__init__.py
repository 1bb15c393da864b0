"""Domain logic, one subpackage per domain: accounts, captures, leases, jobs, labeling, rounds, review, display,
statistics, exports (docs/architecture.md; pyproject.toml's service-domains contract keeps their order). Services
raise `backend.services.errors.DomainError`s; only the API edge maps them to HTTP responses. Every change adds an
audit row (audit.py); work that must wait for the commit goes through transactions.py."""
