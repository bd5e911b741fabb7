#!/usr/bin/env bash
# Build the dashboard and overlay into frontend/dist (served by the backend at /).
# Needs Node >= 20 and npm; package versions come from package-lock.json (npm install
# honours the lock; `npm ci` trips over rollup's optional per-platform packages).
set -euo pipefail
cd "$(dirname "$0")"
if [[ ! -d node_modules ]] || [[ package-lock.json -nt node_modules/.package-lock.json ]]; then
  npm install --no-audit --no-fund --loglevel=error
fi
npm run build
