# The service image used by docker-compose.yml: the Python package and the built front end.
FROM node:20-bookworm-slim AS frontend
WORKDIR /src/frontend
COPY frontend/package.json frontend/package-lock.json ./
RUN npm ci --no-audit --no-fund
COPY frontend/ ./
RUN npm run build

FROM python:3.11-slim-bookworm
WORKDIR /app
COPY pyproject.toml constraints.txt README.md LICENSE ./
COPY backend backend
COPY estimators estimators
COPY simulator simulator
COPY protocol protocol
COPY evaluation evaluation
# editable: the backend serves frontend/dist from beside its sources. The kernels (robot
# pipeline, wearable tracker) are compiled ahead of time (estimators/aot.py: `rehab analyze`
# starts without numba), with a C compiler present for that step only
RUN pip install --no-cache-dir -c constraints.txt -e . \
    && apt-get update -qq && apt-get install -y -qq --no-install-recommends gcc libc6-dev \
    && python -m estimators.aot \
    && python -m compileall -q backend estimators simulator protocol evaluation \
    && apt-get purge -y -qq gcc libc6-dev && apt-get autoremove -y -qq \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --system --home-dir /data rehab && mkdir -p /data && chown rehab /data
COPY --from=frontend /src/frontend/dist frontend/dist
USER rehab
# the wearable filter's kernels, compiled by numba on their first use: cached on the volume, so
# a restarted container loads it (~0.4 s) instead of compiling it again (~40 s)
ENV NUMBA_CACHE_DIR=/data/numba-cache
VOLUME /data
EXPOSE 8080 8081
CMD ["rehab", "serve", "--host", "0.0.0.0", "--port", "8080", "--data-dir", "/data"]
