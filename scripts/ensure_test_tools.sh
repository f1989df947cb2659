#!/usr/bin/env bash
# Test setup: the store's tests run against a real PostgreSQL server that they
# start themselves (tests/test_store.py), and the dashboard's browser tests
# drive the distribution's Chromium through Playwright (tests/test_web.py; no
# browser is downloaded). This installs what is missing from Debian's
# packages (needs root, as CI runs).
set -euo pipefail
need=()
if ! command -v initdb >/dev/null 2>&1 && ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
    need+=(postgresql)
fi
if [ ! -x /usr/bin/chromium ]; then
    need+=(chromium)
fi
if [ ${#need[@]} -eq 0 ]; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "missing for the tests: ${need[*]}; install them (apt-get install ${need[*]}) as root" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
