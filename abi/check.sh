#!/usr/bin/env bash
# The C ABI check (docs/c-api.md, "Upgrading"): the shared library against
# the stored baseline of the release its soname names, with libabigail.
#
#   abi/check.sh            compare (CI runs this)
#   abi/check.sh --update   write the baseline anew (with a release only)
#
# Same soname as the baseline: every change abidiff reports but the
# allowed ones (added functions, fields appended to the sized parameter
# structs; abi/suppressions) fails. A moved soname (a new 0.x minor or
# major release) may break the ABI: the report is shown, the check passes,
# and the release updates the baseline.
set -euo pipefail
cd "$(dirname "$0")/.."
for tool in abidw abidiff readelf; do
  command -v "$tool" >/dev/null || { echo "abi/check.sh: $tool not found (apt-get install abigail-tools binutils)" >&2; exit 2; }
done
echo "abi: building the shared library with debug info (cargo build -p sheaf --profile ci-abi --lib)"
cargo build -q -p sheaf --profile ci-abi --lib
lib=target/ci-abi/libsheaf.so
base=abi/libsheaf.abi
soname=$(readelf -d "$lib" | sed -n 's/.*Library soname: \[\(.*\)\].*/\1/p')
if [ "${1:-}" = "--update" ]; then
  # No paths of this machine in the stored file.
  abidw --no-corpus-path --no-comp-dir-path "$lib" > "$base"
  echo "abi: wrote $base for $soname ($(grep -c '<elf-symbol ' "$base") symbols)"
  exit 0
fi
was=$(sed -n "s/.*soname='\([^']*\)'.*/\1/p" "$base" | head -n 1)
set +e
report=$(abidiff --no-added-syms --suppressions abi/suppressions "$base" "$lib")
status=$?
set -e
if [ "$was" != "$soname" ]; then
  echo "abi: soname $was -> $soname: a new ABI; changes against $was are allowed (abidiff status $status)."
  echo "abi: update the baseline with the release: abi/check.sh --update"
  exit 0
fi
if [ "$status" -ne 0 ]; then
  echo "$report"
  echo "abi: FAILED: $soname changed its ABI (abidiff status $status) without a new soname." >&2
  echo "abi: append fields to parameter structs only, or release a new minor version (0.x) and update $base." >&2
  exit 1
fi
echo "abi: $soname matches $base (nothing but added functions and appended parameter fields)"
