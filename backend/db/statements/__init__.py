"""Hand-written SQL over the models' tables: the one-statement lease and submit of the annotators' hot path
(PostgreSQL), and the passed-over condition both lease statements and the queues use. Above backend.models (it reads
their tables), beside the database plumbing of backend.db (base, session, migrate), which the models build on."""
