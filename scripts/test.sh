#!/usr/bin/env bash
# Quick start, part 2: set up .venv and run the whole test suite (lint included).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
# The browser tests drive Debian's Chromium with Playwright's Python package (never `playwright install`).
if [ ! -x /usr/bin/chromium ]; then
  echo "[handloop] installing Debian's chromium for the browser tests" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq chromium
fi
.venv/bin/ruff check .
# The pages' JSDoc types (frontend/jsconfig.json), checked by TypeScript's compiler (frontend/package.json, from the
# npm registry). Without node the check is skipped, said so; with CI set it must run.
if command -v node >/dev/null && command -v npm >/dev/null; then
  [ -x frontend/node_modules/.bin/tsc ] || (cd frontend && npm ci --no-audit --no-fund --silent)
  (cd frontend && node_modules/.bin/tsc -p jsconfig.json --checkJs --noEmit)
elif [ -n "${CI:-}" ] && [ "${CI}" != "false" ] && [ "${CI}" != "0" ]; then
  echo "[handloop] node and npm are not installed, and CI is set: the JavaScript type check must run (install nodejs and npm)" >&2
  exit 1
else
  echo "[handloop] SKIPPING the JavaScript type check (tsc --checkJs): node and npm are not installed (apt-get install -y nodejs npm)" >&2
fi
# The parts of docs/architecture.md and the directions imports may take ([tool.importlinter] in pyproject.toml).
.venv/bin/lint-imports
# Two processes (HANDLOOP_TEST_WORKERS; 0 runs in this one): half the suite waits on servers, workers and the
# browser, so two overlap well even on 2 cores. --dist loadscope keeps a module's tests (and its fixtures) in one.
workers=${HANDLOOP_TEST_WORKERS:-2}
if [ "$workers" = "0" ]; then
  .venv/bin/python -m pytest "$@"
else
  .venv/bin/python -m pytest -n "$workers" --dist loadscope "$@"
fi
