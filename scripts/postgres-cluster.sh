#!/usr/bin/env bash
# A throwaway PostgreSQL cluster (Debian's postgresql package) for tests and trials.
#   scripts/postgres-cluster.sh start DIR PORT   make DIR/data, serve on 127.0.0.1:PORT and a
#                                                unix socket in DIR; prints the URL
#   scripts/postgres-cluster.sh stop DIR         stop it (fast shutdown; the data stays)
#   scripts/postgres-cluster.sh restart DIR      start a stopped cluster again
#   scripts/postgres-cluster.sh remove DIR       stop it if running and delete DIR
# The server may not run as root: as root, DIR is given to the postgres user the package
# made and every command runs as that user (runuser). fsync is off: test data only.
set -euo pipefail
bin=${PG_BIN:-$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1)}
if [ -z "$bin" ] || [ ! -x "$bin/initdb" ]; then
    echo "postgres-cluster: PostgreSQL not installed (scripts/install-system-deps.sh)" >&2
    exit 1
fi
as_owner() { if [ "$(id -u)" -eq 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }
usage() { echo "usage: $0 start DIR PORT | stop DIR | restart DIR | remove DIR" >&2; exit 2; }
[ $# -ge 2 ] || usage
cmd=$1
dir=$(realpath -m "$2")
case "$cmd" in
start)
    [ $# -eq 3 ] || usage
    port=$3
    mkdir -p "$dir"
    if [ "$(id -u)" -eq 0 ]; then chown postgres "$dir"; fi
    as_owner "$bin/initdb" -D "$dir/data" -A trust -U postgres -E UTF8 --no-sync \
        >"$dir/initdb.log" 2>&1 || { cat "$dir/initdb.log" >&2; exit 1; }
    printf '%s\n' "$port" >"$dir/port"
    as_owner "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 \
        -o "-k $dir -h 127.0.0.1 -p $port -c fsync=off -c max_connections=200" start >/dev/null
    echo "postgresql://postgres@127.0.0.1:$port/postgres"
    ;;
restart)
    port=$(cat "$dir/port")
    as_owner "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 \
        -o "-k $dir -h 127.0.0.1 -p $port -c fsync=off -c max_connections=200" start >/dev/null
    ;;
stop)
    as_owner "$bin/pg_ctl" -D "$dir/data" -m fast -w -t 60 stop >/dev/null
    ;;
remove)
    if [ -f "$dir/data/postmaster.pid" ]; then
        as_owner "$bin/pg_ctl" -D "$dir/data" -m immediate -w -t 60 stop >/dev/null || true
    fi
    rm -rf "$dir"
    ;;
*) usage ;;
esac
