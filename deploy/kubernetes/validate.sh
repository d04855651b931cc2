#!/usr/bin/env bash
# Validates every manifest of deploy/kubernetes/ (README there, "Validation"); .ci/test runs it.
#   1. Kubernetes' own kinds with kubernetes-validate --strict (unknown fields fail), against the
#      target version and against the newest the pinned package knows, so a field removed in a
#      later release shows up before a cluster upgrade;
#   2. the KEDA objects against KEDA's vendored CRD schemas, strictly, plus the references between
#      all the files (validate_crds.py).
# Needs the venv `.ci/install-deps test` builds (target/k8s-venv, deploy/kubernetes/requirements.txt).
# Usage: validate.sh [DIR]   DIR defaults to this script's folder (the negative check in the
#                            README passes a broken copy).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
dir="$(cd "${1:-$here}" && pwd)"
venv="$here/../../target/k8s-venv"
# The version the manifests target (README, "Kubernetes version"), and the newest one the pinned
# kubernetes-validate bundles.
target_version=1.33.0
newest_version=1.37.0
if [ ! -x "$venv/bin/kubernetes-validate" ]; then
  echo "validate.sh: $venv is missing; run .ci/install-deps test" >&2
  exit 1
fi
cd "$dir"
# Every manifest: *.yaml, and the Secret template (*.yaml.template), outside the vendored schemas.
mapfile -t files < <(find . -path ./schemas -prune -o -type f \( -name '*.yaml' -o -name '*.yaml.template' \) -print | sort)
custom=() core=()
for f in "${files[@]}"; do
  # One kind per file (README): a file of KEDA's API group holds custom resources.
  if grep -q '^apiVersion: *keda\.sh/' "$f"; then custom+=("$f"); else core+=("$f"); fi
done
if [ "${#core[@]}" -eq 0 ] || [ "${#custom[@]}" -eq 0 ]; then
  echo "validate.sh: found ${#core[@]} Kubernetes and ${#custom[@]} KEDA manifests in $dir; expected both" >&2
  exit 1
fi
status=0
# kubernetes-validate reports a kind it has no schema for (a misspelt kind or apiVersion) as a
# WARN and still exits 0, so a WARN fails here too.
out="$("$venv/bin/kubernetes-validate" --strict -k "$target_version" -k "$newest_version" "${core[@]}" 2>&1)" || status=1
echo "$out"
if grep -q '^WARN' <<<"$out"; then status=1; fi
"$venv/bin/python" "$here/validate_crds.py" --kubernetes-version "$target_version" \
  --crds "$here/schemas" "${files[@]}" || status=1
if [ "$status" -ne 0 ]; then
  echo "validate.sh: manifests in $dir are INVALID (see ERROR/WARN above)" >&2
else
  echo "validate.sh: ${#files[@]} manifest files valid (Kubernetes $target_version and $newest_version, KEDA CRDs)" >&2
fi
exit "$status"
