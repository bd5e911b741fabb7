#!/usr/bin/env bash
# A throwaway PostgreSQL cluster for the storage tests, on a free loopback port.
#
#   scripts/postgres-test-server.sh start [DIR]   # prints the SQLAlchemy URL on stdout
#   scripts/postgres-test-server.sh stop DIR      # stops it and deletes DIR
#
#   export REHAB_TEST_POSTGRES_URL=$(scripts/postgres-test-server.sh start /tmp/rehab-pg)
#
# Needs Debian's `postgresql` package (or initdb/pg_ctl on PATH). PostgreSQL refuses to run as
# root, so as root the cluster runs as the `postgres` user. Durability is switched off: the
# data is thrown away anyway, and fsync would dominate the test time. Trust authentication,
# bound to 127.0.0.1 only.
set -euo pipefail

find_bin() {
    local name=$1 found
    found=$(ls -d /usr/lib/postgresql/*/bin/"$name" 2>/dev/null | sort -V | tail -n 1 || true)
    if [[ -z "$found" ]]; then
        found=$(command -v "$name" || true)
    fi
    if [[ -z "$found" ]]; then
        echo "postgres-test-server: $name not found (apt-get install postgresql)" >&2
        exit 127
    fi
    echo "$found"
}

as_owner() {
    if [[ $(id -u) -eq 0 ]]; then
        runuser -u postgres -- "$@"
    else
        "$@"
    fi
}

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

cmd=${1:-start}
case "$cmd" in
start)
    dir=${2:-$(mktemp -d /tmp/rehab-pg.XXXXXX)}
    mkdir -p "$dir"
    initdb=$(find_bin initdb)
    pg_ctl=$(find_bin pg_ctl)
    if [[ $(id -u) -eq 0 ]]; then
        chown postgres: "$dir"
        chmod 0700 "$dir"
    fi
    port=$(free_port)
    as_owner "$initdb" -D "$dir/data" -U rehab --auth=trust --encoding=UTF8 --no-sync >"$dir/initdb.log" 2>&1 ||
        { cat "$dir/initdb.log" >&2; exit 1; }
    as_owner "$pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 30 start \
        -o "-p $port -k $dir -c listen_addresses=127.0.0.1 -c fsync=off -c synchronous_commit=off -c full_page_writes=off" \
        >/dev/null || { cat "$dir/server.log" >&2; exit 1; }
    echo "postgresql+psycopg://rehab@127.0.0.1:$port/postgres"
    ;;
stop)
    dir=${2:?usage: $0 stop DIR}
    pg_ctl=$(find_bin pg_ctl)
    if [[ -d "$dir/data" ]]; then
        as_owner "$pg_ctl" -D "$dir/data" -m immediate -w stop >/dev/null 2>&1 || true
    fi
    rm -rf "$dir"
    ;;
*)
    echo "usage: $0 start [DIR] | stop DIR" >&2
    exit 2
    ;;
esac
