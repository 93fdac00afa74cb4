#!/usr/bin/env bash
# The web panel's setup, run by the README's test command and so by .ci/run:
# uPlot from the npm registry into web/node_modules (the panel serves it; nothing third-party is committed),
# and Debian's Chromium for the browser tests (Playwright drives /usr/bin/chromium; no browser download).
set -eu
cd "$(dirname "$0")"
npm ci --no-audit --no-fund --loglevel=error
if [ ! -x /usr/bin/chromium ]; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "web/setup.sh: /usr/bin/chromium is missing: run 'sudo apt-get install chromium' (browser tests)" >&2
        exit 1
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
