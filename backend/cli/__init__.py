"""The `handloop` command line. Each command lives in its own module under `commands/`."""
