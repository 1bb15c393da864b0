#!/usr/bin/env bash
# Quick start, part 1: set up .venv and run the demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/handloop demo "$@"
