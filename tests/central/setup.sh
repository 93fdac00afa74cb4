#!/usr/bin/env bash
# The central-history tests' setup, run by the README's test command and so by .ci/run: Debian's PostgreSQL
# server (the tests start a throwaway cluster of it on a unix socket; station/central/server.py). Nothing is
# started here and no cluster is created: the package's binaries are all the tests need.
set -eu
if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "tests/central/setup.sh: PostgreSQL is missing: run 'sudo apt-get install postgresql'" >&2
        exit 1
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null
fi
