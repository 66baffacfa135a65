#!/usr/bin/env bash
# The image's HEALTHCHECK: GET /healthz on the port of RIGSERVE_BIND, 200 or fail.
# bash's /dev/tcp instead of curl keeps curl and its libraries out of the image.
# Usage: healthcheck.sh [PATH]  (default /healthz; image_build.sh also asks /readyz)
set -u
path=${1:-/healthz}
bind=${RIGSERVE_BIND:-127.0.0.1:8080}
port=${bind##*:}
host=${bind%:*}
host=${host#[}
host=${host%]}
# A wildcard bind is reached on loopback; a specific address only on itself.
case "$host" in 0.0.0.0 | "") host=127.0.0.1 ;; ::) host=::1 ;; esac
exec timeout 5 bash -c '
  exec 3<>"/dev/tcp/$0/$1" || exit 1
  printf "GET %s HTTP/1.0\r\nHost: localhost\r\n\r\n" "$2" >&3
  IFS= read -r status <&3 || exit 1
  case "$status" in "HTTP/1."?" 200 "*) exit 0 ;; *) echo "$2: $status" >&2; exit 1 ;; esac
' "$host" "$port" "$path"
