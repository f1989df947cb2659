#!/usr/bin/env bash
# A plain `pip install chaintwin` (no extras) in a fresh virtual environment runs
# the batch job: generate, calibrate, weigh, monitor, ingest into SQLite, report;
# `chaintwin serve` there names the extra it needs (exit 2), and `--help` works.
#
#   bash scripts/check_plain_install.sh [VENV]      (default VENV: a new temporary folder)
#
# Takes a few minutes (pip downloads and installs the dependencies). With an
# existing VENV, only chaintwin itself is reinstalled.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
VENV=${1:-$(mktemp -d)/venv}
WORK=$(mktemp -d)
PYTHON=${PYTHON:-python3}

if [ ! -x "$VENV/bin/chaintwin" ]; then
    "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q "$ROOT"
else
    "$VENV/bin/python" -m pip install -q --no-deps --force-reinstall "$ROOT"
fi
CT="$VENV/bin/chaintwin"

for extra in fastapi uvicorn asyncua watchfiles httpx psycopg distributed dask plotly; do
    if "$VENV/bin/python" -c "import $extra" 2>/dev/null; then
        echo "FAIL: $extra is installed by the plain install" >&2
        exit 1
    fi
done

cd "$WORK"
"$CT" --help >/dev/null
"$CT" examples --out ex >/dev/null
PROFILE=ex/profiles/$(ls ex/profiles | head -n1)
"$CT" generate --profile "$PROFILE" --days 6 --per-day 3 --fault friction:0.5 --onset 3 --out fleet/
"$CT" calibrate --profile "$PROFILE" fleet/calibration/*.csv --out cal.json
"$CT" weigh --calibration cal.json fleet/*.csv --json >weigh.json
"$CT" monitor --profile "$PROFILE" --calibration cal.json fleet/*.csv --json >monitor.json
mkdir profiles && cp "$PROFILE" profiles/
"$CT" calibrate --profile "$PROFILE" fleet/calibration/*.csv --db sqlite:///plant.db
"$CT" ingest fleet/ --profiles profiles/ --db sqlite:///plant.db
"$CT" report --db sqlite:///plant.db --fleet --out fleet.html
test -s weigh.json && test -s monitor.json && test -s fleet.html

set +e
"$CT" serve --db sqlite:///plant.db 2>serve.err
code=$?
set -e
if [ "$code" != 2 ] || ! grep -q "pip install 'chaintwin\[web\]'" serve.err; then
    echo "FAIL: serve gave exit $code: $(cat serve.err)" >&2
    exit 1
fi
echo "serve says: $(cat serve.err)"
echo "OK: the plain install in $VENV ran the batch job in $WORK"
