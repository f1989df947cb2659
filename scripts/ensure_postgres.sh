#!/usr/bin/env bash
# Test setup: the store's tests run against a real PostgreSQL server that they
# start themselves (tests/test_store.py); this installs its binaries when the
# machine has none (Debian's packages; needs root, as CI runs).
set -euo pipefail
if command -v initdb >/dev/null 2>&1 || ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "PostgreSQL server binaries are missing; install them (apt-get install postgresql) as root" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends postgresql >/dev/null
