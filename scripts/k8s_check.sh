#!/usr/bin/env bash
# Validates deploy/k8s: `kubectl apply --dry-run=client` when a cluster is reachable
# (client dry-run still downloads the API server's schema), otherwise an offline
# schema check with kubernetes-validate (PyPI; scripts/setup.sh installs it), strict,
# so misspelled fields fail too. The kustomization is rendered first, so what is
# checked is what `kubectl apply -k` would send.
# Exit status: 0 valid, 1 invalid, 3 no validator here (tests/deploy.rs skips on 3).
set -euo pipefail
cd "$(dirname "$0")/.."
k8s=deploy/k8s
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

if command -v kubectl >/dev/null 2>&1; then
  kubectl kustomize "$k8s" >"$out/rendered.yaml"
else
  # Without kustomize the plain files are what is checked (it only adds labels and
  # the image tag).
  sed -n 's/^  - \(.*\.yaml\)$/\1/p' "$k8s/kustomization.yaml" | while read -r f; do
    cat "$k8s/$f"; echo "---"
  done >"$out/rendered.yaml"
fi
files=("$out/rendered.yaml" "$k8s/secret.example.yaml")

# Only with a context configured: kubectl's fallback server is localhost:8080, which
# is rigserve's own default port.
if command -v kubectl >/dev/null 2>&1 && kubectl config current-context >/dev/null 2>&1 \
   && kubectl version --request-timeout=5s >/dev/null 2>&1; then
  echo "k8s_check: kubectl apply --dry-run=client"
  for f in "${files[@]}"; do kubectl apply --dry-run=client -f "$f"; done
  exit 0
fi

if command -v kubernetes-validate >/dev/null 2>&1; then
  echo "k8s_check: no reachable cluster; kubernetes-validate --strict (offline schemas)"
  kubernetes-validate --strict --quiet "${files[@]}" || exit 1
  echo "k8s_check: $(grep -c '^kind:' "${files[@]}" | awk -F: '{n += $NF} END {print n}') resources valid"
  exit 0
fi

echo "k8s_check: neither a reachable cluster nor kubernetes-validate (scripts/setup.sh installs it)" >&2
exit 3
