#!/usr/bin/env bash
# The Dockerfile's steps without Docker (CI and this machine have no engine): release
# build, ONNX Runtime from its wheel, the runtime layout under ROOT, then a smoke test
# of that layout run the way the image runs it. tests/deploy.rs checks that this file
# and the Dockerfile name the same paths and environment.
#
# Usage: scripts/image_build.sh [--binary PATH] [--root DIR] [--no-smoke]
#   --binary  a prebuilt rigserve (tests pass the one `cargo test --release` built)
#   --root    where the layout goes (default target/image-root): ROOT/app/rigserve,
#             ROOT/app/models, ROOT/app/lib/libonnxruntime.so.1.31.1, ROOT/data
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD

binary=
root=target/image-root
smoke=1
while [ $# -gt 0 ]; do
  case "$1" in
    --binary) binary=$2; shift 2 ;;
    --root) root=$2; shift 2 ;;
    --no-smoke) smoke=0; shift ;;
    *) echo "image_build: unknown argument $1" >&2; exit 2 ;;
  esac
done

# The Dockerfile's ENV, as the image sees it (paths under / are rebased to ROOT here).
IMAGE_ENV=(
  RIGSERVE_BIND=0.0.0.0:8080
  RIGSERVE_DATA_DIR=/data
  RIGSERVE_MODELS=/app/models
  RIGSERVE_ORT_LIB=/app/lib/libonnxruntime.so.1.31.1
  RIGSERVE_LOG_JSON=true
)
IMAGE_UID=10001

# --- build stage
if [ -z "$binary" ]; then
  cargo build --release --locked --bin rigserve
  binary=target/release/rigserve
fi
[ -x "$binary" ] || { echo "image_build: $binary is not an executable" >&2; exit 1; }

# --- ort stage (cached in .onnxruntime/, where setup.sh puts it)
./scripts/fetch_ort.sh .onnxruntime

# --- runtime stage: the same files at the same places as the image's COPY lines
rm -rf "$root"
install -D -m 755 "$binary" "$root/app/rigserve"
install -D -m 644 .onnxruntime/libonnxruntime.so.1.31.1 "$root/app/lib/libonnxruntime.so.1.31.1"
cp -R models "$root/app/models"
# As in .dockerignore: a library.json built locally stays out; library.bin ships.
rm -f "$root/app/models/library.json"
install -D -m 755 deploy/healthcheck.sh "$root/app/healthcheck.sh"
mkdir -p "$root/data"
root=$(cd "$root" && pwd)
echo "image_build: layout in $root ($(du -sh "$root" | cut -f1))"
[ "$smoke" = 1 ] || exit 0

# --- smoke test: the layout run as the image runs it, then drained with SIGTERM
work=$(mktemp -d)
pid=
cleanup() {
  [ -n "$pid" ] && kill -KILL "$pid" 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
fail() {
  echo "image_build: smoke test FAILED: $*" >&2
  echo "--- server log (last 30 lines)" >&2
  tail -n 30 "$work/stderr" >&2 || true
  exit 1
}

# Only the image's variables (env -i), with its paths under ROOT; a port the kernel
# picks (read back from the "listening" line); data in a temp dir like a fresh volume.
env_args=()
for kv in "${IMAGE_ENV[@]}"; do
  k=${kv%%=*} v=${kv#*=}
  case "$v" in /*) v=$root$v ;; esac
  env_args+=("$k=$v")
done
env_args+=(RIGSERVE_BIND=127.0.0.1:0 "RIGSERVE_DATA_DIR=$work/data" PATH=/usr/bin:/bin)
mkdir -p "$work/data"

# As root (CI), run as the image's uid, so the layout must be readable and the data
# dir writable by a user that owns nothing else, as in the container.
as_user=()
if [ "$(id -u)" = 0 ]; then
  chown "$IMAGE_UID:$IMAGE_UID" "$work/data"
  chmod 755 "$work"
  as_user=(setpriv --reuid="$IMAGE_UID" --regid="$IMAGE_UID" --clear-groups)
  # A checkout under a private home (0700) is out of that user's reach: say so
  # and run as root rather than fail on where the checkout happens to be.
  if ! "${as_user[@]}" test -x "$root/app/rigserve" -a -r "$root/app/models"; then
    echo "image_build: uid $IMAGE_UID cannot reach $root; smoke test runs as root" >&2
    as_user=()
  fi
fi

# The log files exist before the server starts: the background subshell opens its
# redirections only when it is scheduled, and on a busy machine the first poll below
# could otherwise read a file not yet there (fatal under `set -e`).
: >"$work/stdout"
: >"$work/stderr"
(cd "$root/app" && exec "${as_user[@]}" env -i "${env_args[@]}" ./rigserve serve) \
  >>"$work/stdout" 2>>"$work/stderr" &
pid=$!

port=
for _ in $(seq 1 600); do
  port=$(sed -n 's|^rigserve listening on http://127.0.0.1:\([0-9]*\)$|\1|p' "$work/stdout")
  [ -n "$port" ] && break
  kill -0 "$pid" 2>/dev/null || fail "the server exited before listening"
  sleep 0.1
done
[ -n "$port" ] || fail "no 'listening' line within 60 s"
base=http://127.0.0.1:$port

# The image's own health check, against both probes Kubernetes uses.
for probe in /healthz /readyz; do
  ok=0
  for _ in $(seq 1 100); do
    if RIGSERVE_BIND=127.0.0.1:$port "$root/app/healthcheck.sh" "$probe" 2>/dev/null; then ok=1; break; fi
    sleep 0.1
  done
  [ "$ok" = 1 ] || fail "$probe did not answer 200 within 10 s"
done
curl -fsS "$base/readyz" | grep -q '"skeleton_model":"loaded"' \
  || fail "/readyz does not report the skeleton model loaded (ORT library or models missing?)"
grep -q '"message":"listening"' "$work/stderr" || fail "no JSON log line (RIGSERVE_LOG_JSON)"

# A small OBJ through the synchronous endpoint: the answer must be a GLB.
code=$(curl -sS -o "$work/rigged.glb" -w '%{http_code}' --max-time 120 \
  -H 'content-type: model/obj' --data-binary @tests/corpus/base.obj "$base/v1/rig?seed=1")
[ "$code" = 200 ] || fail "POST /v1/rig answered $code: $(head -c 300 "$work/rigged.glb")"
[ "$(head -c 4 "$work/rigged.glb")" = glTF ] || fail "POST /v1/rig did not return a GLB"

# A job left queued or running at SIGTERM: the drain must finish or re-queue it and
# exit 0 within the drain time (20 s default) plus a margin.
curl -fsS -o /dev/null -H 'content-type: model/obj' --data-binary @tests/corpus/base.obj \
  "$base/v1/jobs?seed=2" || fail "POST /v1/jobs failed"
kill -TERM "$pid"
start=$(date +%s)
rc=
for _ in $(seq 1 250); do
  if ! kill -0 "$pid" 2>/dev/null; then
    wait "$pid" && rc=0 || rc=$?
    break
  fi
  sleep 0.1
done
[ -n "$rc" ] || fail "still running 25 s after SIGTERM"
pid=
[ "$rc" = 0 ] || fail "exit status $rc after SIGTERM"
grep -q '"message":"stopped"' "$work/stderr" || fail "no 'stopped' log line after SIGTERM"
echo "image_build: smoke test passed (port $port, /v1/rig GLB $(wc -c <"$work/rigged.glb") bytes, stopped $(($(date +%s) - start)) s after SIGTERM)"
