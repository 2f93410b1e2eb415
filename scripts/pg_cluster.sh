#!/usr/bin/env bash
# A throwaway PostgreSQL cluster for the PostgreSQL store's tests and benchmarks
# (server/crates/engine/resecta-store: tests/store.rs, examples/append_latency.rs).
#
# Usage:
#   scripts/pg_cluster.sh start DIR   # prints `export RESECTA_TEST_PG=…` lines, also kept in DIR/env
#   scripts/pg_cluster.sh stop DIR    # stops the cluster (pg_ctl stop -m fast) and removes DIR
#
# The cluster listens on 127.0.0.1 only, on a free port, with its Unix socket in DIR; local
# connections are trusted (it is throwaway), except for the role resecta_pw, which must give its
# password over TCP (the wrong-password test). fsync stays on: commit latency is measured with it.
# When openssl is present, TLS is on with a fresh CA (DIR/ca.crt, exported as RESECTA_TEST_PG_CA)
# and a server certificate for the name "localhost" only (not for 127.0.0.1: the verify-ca and
# verify-full tests rely on that).
#
# PostgreSQL runs as an unprivileged user: run as root, the script uses the `postgres` system user
# (created if missing); otherwise the caller's. Server binaries: $PG_BIN, else PostgreSQL 15's
# Debian directory, else the newest /usr/lib/postgresql/*/bin, else initdb on PATH.
set -euo pipefail

die() { echo "pg_cluster.sh: $*" >&2; exit 1; }

usage() { die "usage: $0 start DIR | stop DIR"; }

[ $# -eq 2 ] || usage
cmd=$1
dir=$2

find_bin() {
  local d
  for d in "${PG_BIN:-}" /usr/lib/postgresql/15/bin $(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V -r); do
    if [ -n "$d" ] && [ -x "$d/initdb" ] && [ -x "$d/pg_ctl" ]; then echo "$d"; return; fi
  done
  if command -v initdb >/dev/null && command -v pg_ctl >/dev/null; then
    dirname "$(readlink -f "$(command -v initdb)")"; return
  fi
  die "PostgreSQL server binaries (initdb, pg_ctl) not found: install them (apt-get install -y postgresql) or set PG_BIN"
}

# Runs a command as the cluster's owner.
if [ "$(id -u)" = 0 ]; then
  owner=postgres
  as_owner() {
    if command -v runuser >/dev/null; then runuser -u "$owner" -- "$@"
    else su -s /bin/sh "$owner" -c "$(printf '%q ' "$@")"; fi
  }
else
  owner=$(id -un)
  as_owner() { "$@"; }
fi

free_port() {
  if command -v python3 >/dev/null; then
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
    return
  fi
  local p
  for _ in $(seq 200); do
    p=$((20000 + RANDOM % 40000))
    if ! (exec 3<>"/dev/tcp/127.0.0.1/$p") 2>/dev/null; then echo "$p"; return; fi
  done
  die "no free port found"
}

start() {
  local bin port
  bin=$(find_bin)
  if [ "$owner" = postgres ] && ! id postgres >/dev/null 2>&1; then
    useradd --system --user-group --home-dir /nonexistent --no-create-home --shell /usr/sbin/nologin postgres \
      || die "cannot create the postgres system user"
  fi
  [ ! -e "$dir/data" ] || die "$dir/data exists: stop the cluster first ($0 stop $dir)"
  mkdir -p "$dir"
  dir=$(cd "$dir" && pwd)
  touch "$dir/.resecta-pg-cluster"
  chown -R "$owner" "$dir"
  chmod 0700 "$dir"
  as_owner test -w "$dir" || die "$owner cannot write $dir (is a parent directory closed to it?)"

  as_owner "$bin/initdb" -D "$dir/data" -U postgres -E UTF8 --locale=C --auth=trust >"$dir/initdb.log" 2>&1 \
    || { cat "$dir/initdb.log" >&2; die "initdb failed"; }

  local ssl=off ca_env=""
  if command -v openssl >/dev/null; then
    (
      cd "$dir"
      openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 3650 \
        -subj "/CN=resecta throwaway test CA" -keyout ca.key -out ca.crt \
        -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"
      openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -subj "/CN=localhost" \
        -keyout server.key -out server.csr
      printf '%s\n' "subjectAltName=DNS:localhost" "basicConstraints=critical,CA:FALSE" \
        "keyUsage=critical,digitalSignature" "extendedKeyUsage=serverAuth" >server.ext
      openssl x509 -req -in server.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 3650 \
        -extfile server.ext -out server.crt
      rm -f server.csr server.ext ca.srl ca.key
    ) >"$dir/openssl.log" 2>&1 || { cat "$dir/openssl.log" >&2; die "openssl failed"; }
    chown "$owner" "$dir"/server.key "$dir"/server.crt "$dir"/ca.crt
    chmod 0600 "$dir/server.key"
    chmod 0644 "$dir/ca.crt"
    ssl=on
    ca_env="export RESECTA_TEST_PG_CA=$dir/ca.crt"
  fi

  port=$(free_port)
  cat >>"$dir/data/postgresql.conf" <<EOF

# pg_cluster.sh: a throwaway cluster for tests
listen_addresses = '127.0.0.1'
port = $port
unix_socket_directories = '$dir'
max_connections = 300
fsync = on
synchronous_commit = on
ssl = $ssl
ssl_cert_file = '$dir/server.crt'
ssl_key_file = '$dir/server.key'
EOF
  cat >"$dir/data/pg_hba.conf" <<EOF
# pg_cluster.sh: trusted local connections (throwaway), a password for resecta_pw over TCP.
local all all trust
host all resecta_pw 127.0.0.1/32 scram-sha-256
host all all 127.0.0.1/32 trust
EOF
  as_owner "$bin/pg_ctl" -D "$dir/data" -l "$dir/postgres.log" -w -t 60 start >/dev/null \
    || { tail -n 30 "$dir/postgres.log" >&2 || true; die "pg_ctl start failed"; }
  local ready="$bin/pg_isready"
  [ -x "$ready" ] || ready=pg_isready
  for _ in $(seq 60); do
    if "$ready" -q -h 127.0.0.1 -p "$port" -U postgres; then break; fi
    sleep 0.5
  done
  "$ready" -q -h 127.0.0.1 -p "$port" -U postgres || die "the cluster did not become ready (log: $dir/postgres.log)"

  {
    echo "export RESECTA_TEST_PG=postgres://postgres@127.0.0.1:$port/postgres"
    [ -z "$ca_env" ] || echo "$ca_env"
  } >"$dir/env"
  echo "$bin" >"$dir/bin"
  cat "$dir/env"
}

stop() {
  [ -d "$dir" ] || return 0
  [ -e "$dir/.resecta-pg-cluster" ] || die "$dir is not a cluster of this script"
  local bin
  bin=$(cat "$dir/bin" 2>/dev/null || find_bin)
  if [ -f "$dir/data/postmaster.pid" ]; then
    as_owner "$bin/pg_ctl" -D "$dir/data" -m fast -w -t 60 stop >/dev/null || echo "pg_cluster.sh: pg_ctl stop failed" >&2
  fi
  rm -rf "$dir"
}

case "$cmd" in
  start) start ;;
  stop) stop ;;
  *) usage ;;
esac
