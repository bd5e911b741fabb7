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
# editable: the backend serves frontend/dist from beside its sources
RUN pip install --no-cache-dir -c constraints.txt -e . \
    && useradd --system --home-dir /data rehab && mkdir -p /data && chown rehab /data
COPY --from=frontend /src/frontend/dist frontend/dist
USER rehab
# the wearable filter's kernel, compiled by numba on its first use: cached on the volume, so
# a restarted container loads it (~0.4 s) instead of compiling it again (~40 s)
ENV NUMBA_CACHE_DIR=/data/numba-cache
VOLUME /data
EXPOSE 8080 8081
CMD ["rehab", "serve", "--host", "0.0.0.0", "--port", "8080", "--data-dir", "/data"]
