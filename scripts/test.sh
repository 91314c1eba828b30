#!/usr/bin/env bash
# The whole test suite on a fresh machine, on every core: a venv with qchain and its test extra, and
# Debian's Chromium for the real-browser test of the live viewer (tests/test_browser.py).
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "scripts/test.sh: tests/test_browser.py needs Debian's chromium (sudo apt-get install chromium)" >&2
  fi
fi
python3 -m venv .venv
.venv/bin/pip install -q -e ".[test]"
# one pytest-xdist worker a core; worksteal: the long tests (the install warm-up, the
# process-killing and convergence studies) do not queue behind each other on one worker
exec .venv/bin/python -m pytest -q -n auto --dist worksteal "$@"
