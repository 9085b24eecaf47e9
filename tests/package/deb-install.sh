#!/usr/bin/env bash
# The Debian package made from this build, installed into a fresh Debian 12 root with
# `apt-get install ./slamd_*.deb` and checked there as a user meets it (scripts/fresh-debian
# --deb runs tests/package/check-installed.sh in the root). Minutes: the first run debootstraps
# the root that scripts/fresh-debian keeps in its cache, and every run fetches the package's
# libraries from Debian's archive. Skips (77) only when not root or when a tool is missing
# (scripts/deps --test installs them).
#   tests/package/deb-install.sh BUILD_DIR WORK_DIR SOURCE_DIR VERSION
set -euo pipefail
build=$1 work=$2 source=$3 version=$4

if ((EUID != 0)); then
  echo "SKIP: needs root (debootstrap, chroot and mount)"
  exit 77
fi
for tool in debootstrap cpack dpkg-deb dpkg-shlibdeps file help2man; do
  if ! command -v "$tool" > /dev/null; then
    echo "SKIP: $tool is missing (scripts/deps --test installs it)"
    exit 77
  fi
done

rm -rf "$work"  # this test's own folder in the build tree
deb=$(bash "$source/tests/package/make-deb.sh" "$build" "$work" "$version")
echo "made $deb"
exec bash "$source/scripts/fresh-debian" --deb "$deb"
