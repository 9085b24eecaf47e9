#!/usr/bin/env bash
# Makes the Debian package from a build folder (cpack -G DEB, which builds every target first)
# into WORK, replacing an earlier package and cpack's staging there, and prints the path of
# WORK/slamd_VERSION_ARCH.deb. Used by scripts/package and the package tests.
#   tests/package/make-deb.sh BUILD_DIR WORK_DIR VERSION
set -euo pipefail
build=$1 work=$2 version=$3
mkdir -p "$work"
rm -rf "$work/_CPack_Packages" "$work"/slamd_*.deb
if ! cpack -G DEB -B "$work" --config "$build/CPackConfig.cmake" > "$work/cpack.log" 2>&1; then
  echo "cpack -G DEB failed:" >&2
  cat "$work/cpack.log" >&2
  exit 1
fi
deb=$work/slamd_${version}_$(dpkg --print-architecture).deb
if [[ ! -f $deb ]]; then
  echo "cpack made no $deb (log: $work/cpack.log); it made:" >&2
  ls "$work" >&2
  exit 1
fi
echo "$deb"
