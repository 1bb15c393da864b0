"""One module per CLI command (or family of commands); each exposes `register(app, bench)`.

deferred: every module here is imported to build `handloop --help`, which must start fast and without torch, so
each command imports what it uses (the settings, the database, the compute core, the benchmarks) inside itself;
standard-library modules are imported at the top (tests/test_import_contracts.py checks both).
"""
