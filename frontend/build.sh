#!/usr/bin/env bash
# Build the dashboard and overlay into frontend/dist (served by the backend at /).
# Needs Node >= 20 and npm; packages come from the npm registry (package-lock.json).
set -euo pipefail
cd "$(dirname "$0")"
if [[ ! -d node_modules ]] || [[ package-lock.json -nt node_modules/.package-lock.json ]]; then
  npm ci --no-audit --no-fund
fi
npm run build
