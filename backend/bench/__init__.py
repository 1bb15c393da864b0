"""Benchmarks behind `handloop bench NAME`. Each returns a dict; `common.emit` prints it as JSON."""
