#!/usr/bin/env bash
# The Debian package made from this build (cpack -G DEB) and checked without installing it: its
# name and control fields, Depends from dpkg-shlibdeps, every file it must hold and nothing
# else, conffiles and maintainer scripts, lintian, systemd-analyze verify and security on the
# unit, the manual pages, and the unpacked programs: --version, and slamd finding the unpacked
# robot description and page (not the source tree's) and serving them.
# Skips (77) only when a tool is missing; scripts/deps --test installs them all.
#   tests/package/deb-package.sh BUILD_DIR WORK_DIR SOURCE_DIR VERSION
set -euo pipefail
build=$1 work=$2 source=$3 version=$4

for tool in cpack dpkg-deb dpkg-shlibdeps file help2man lintian systemd-analyze man; do
  if ! command -v "$tool" > /dev/null; then
    echo "SKIP: $tool is missing (scripts/deps --test installs it)"
    exit 77
  fi
done
fail() {
  echo "FAIL: $*"
  exit 1
}

rm -rf "$work"  # this test's own folder in the build tree
deb=$(bash "$source/tests/package/make-deb.sh" "$build" "$work" "$version")
echo "made $deb ($(du -k "$deb" | cut -f1) KiB)"

# Control fields. Depends come from dpkg-shlibdeps: the runtime libraries of every program.
dpkg-deb --field "$deb"
[[ $(dpkg-deb --field "$deb" Package) == slamd ]] || fail "Package is not slamd"
[[ $(dpkg-deb --field "$deb" Version) == "$version" ]] || fail "Version is not $version"
depends=$(dpkg-deb --field "$deb" Depends)
for library in libc6 libstdc++6 libgcc-s1 libtbb libpng16 libcpp-httplib; do
  [[ ", $depends" == *", $library"* ]] || fail "Depends lacks $library: $depends"
done

# Files: everything below must be there, and nothing outside these places.
dpkg-deb --contents "$deb" | awk '{print $6}' | sed 's|^\./|/|; s|/$||' | sort > "$work/files"
expected=(/etc/default/slamd /lib/systemd/system/slamd.service
  /usr/share/doc/slamd/copyright /usr/share/doc/slamd/changelog.gz
  /usr/share/slamd/web/index.html /usr/share/slamd/web/node_modules/uplot/dist/uPlot.iife.min.js
  /usr/share/slamd/web/node_modules/uplot/dist/uPlot.min.css)
for program in slamd slam-sim slam-link slam-replay slam-evaluate slam-relations slam-tune slamd-load; do
  expected+=("/usr/bin/$program" "/usr/share/man/man1/$program.1.gz")
done
# The page's files and every robot description and parameter set of config/, as the source tree
# holds them.
while IFS= read -r file; do
  expected+=("/usr/share/slamd/$file")
done < <(cd "$source" && find web -maxdepth 1 -type f ! -name 'package*.json' &&
  find config -name '*.json')
for path in "${expected[@]}"; do
  grep -qxF "$path" "$work/files" || fail "the package lacks $path"
done
unexpected=$(grep -v -E '^(/usr/bin|/usr/share/slamd|/usr/share/doc/slamd|/usr/share/man/man1|/lib/systemd/system|/etc/default)(/|$)' "$work/files" |
  grep -v -x -E '/|/usr|/usr/share|/usr/share/doc|/usr/share/man|/lib|/lib/systemd|/etc' || true)
[[ -z $unexpected ]] || fail "unexpected files in the package: $unexpected"
echo "files: ${#expected[@]} expected ones present, nothing elsewhere"

# Control files: /etc/default/slamd is a conffile; maintainer scripts are executable sh.
dpkg-deb --control "$deb" "$work/control"
[[ $(cat "$work/control/conffiles") == /etc/default/slamd ]] || fail "conffiles: $(cat "$work/control/conffiles")"
for script in postinst prerm postrm; do
  [[ -x $work/control/$script ]] || fail "$script is missing or not executable"
  sh -n "$work/control/$script" || fail "$script is not valid sh"
done
dpkg-deb --extract "$deb" "$work/root"
changelog=$(zcat "$work/root/usr/share/doc/slamd/changelog.gz" | head -n 1)
[[ $changelog == "slamd ($version) "* ]] ||
  fail "the changelog's latest entry is '$changelog', not $version (packaging/deb/changelog)"

# lintian: no error and no warning. Its info tags are printed and left, for these reasons:
#   hardening-no-bindnow, hardening-no-fortify-functions: the project's own flags (CMakeLists.txt),
#     not dpkg-buildflags'; Debian's toolchain already gives PIE, RELRO and stack protection;
#   binary-has-unneeded-section .comment: CPack strips with plain `strip`;
#   package-contains-documentation-outside-usr-share-doc: web/index.html is the page slamd serves;
#   spelling-error-in-binary "characteer": "control character in interface" (hw_link/candump.cpp)
#     is stored as pieces in the code; lintian reads two of them run together;
#   package-supports-alternative-init-but-no-init.d-script: slamd ships a systemd unit only.
echo "lintian -I $deb:"
lintian -I --fail-on error,warning "$deb" 2> "$work/lintian.err" || {
  cat "$work/lintian.err"
  fail "lintian reports errors or warnings (above)"
}
grep -v 'running with root privileges is not recommended' "$work/lintian.err" || true
echo "lintian: no error, no warning"

# The unit, against the unpacked tree (ExecStart must exist there) with the host's units beside
# it (systemd-analyze wants sysinit.target and the like). Any message fails: systemd-analyze
# only warns about a misspelt key or a bad value.
cp -an /lib/systemd/system/. "$work/root/lib/systemd/system/"
if ! systemd-analyze verify --man=no --root="$work/root" slamd.service > "$work/verify.out" 2>&1 ||
  [[ -s $work/verify.out ]]; then
  cat "$work/verify.out"
  fail "systemd-analyze verify slamd.service"
fi
echo "systemd-analyze verify slamd.service: no message"
systemd-analyze security --offline=yes --root="$work/root" slamd.service > "$work/security.out" 2>&1 ||
  { cat "$work/security.out"; fail "systemd-analyze security"; }
exposure=$(sed -n 's/.*Overall exposure level for slamd.service: \([0-9.]*\).*/\1/p' "$work/security.out")
echo "systemd-analyze security: exposure $exposure"
awk -v e="$exposure" 'BEGIN { exit !(e != "" && e <= 2.5) }' ||
  { cat "$work/security.out"; fail "the unit's exposure rose above 2.5 (it was 2.1)"; }

# Manual pages: they render without warnings, and name the installed files, never the build's.
for page in "$work"/root/usr/share/man/man1/*.1.gz; do
  warnings=$(LC_ALL=C.UTF-8 MANROFFSEQ='' MANWIDTH=80 man --warnings -E UTF-8 -l "$page" 2>&1 > /dev/null || true)
  [[ -z $warnings ]] || fail "$page: $warnings"
  ! zgrep -qF "$(sed 's/-/\\-/g' <<< "$source")" "$page" && ! zgrep -qF "$source" "$page" ||
    fail "$page names the source tree $source"
done
zgrep -q '/usr/share/slamd/config/marxbot.robot.json' "$work/root/usr/share/man/man1/slamd.1.gz" ||
  fail "slamd.1 does not name the installed robot description"
echo "manual pages: render cleanly, name /usr/share/slamd"

# The unpacked programs: every one answers --version; slamd and slam-sim default to the unpacked
# robot description and slamd to the unpacked page (they look beside themselves first).
bin=$work/root/usr/bin
data=$work/root/usr/share/slamd
for program in slamd slam-sim slam-link slam-replay slam-evaluate slam-relations slam-tune slamd-load; do
  printed=$("$bin/$program" --version)
  [[ $printed == "$program $version" ]] || fail "$program --version printed '$printed'"
done
echo "--version: every program prints its name and $version"
for program in slamd slam-sim slam-link; do
  "$bin/$program" --help | grep -qF "$data/config/marxbot.robot.json" ||
    fail "$program --help does not default --robot to $data/config/marxbot.robot.json"
done
"$bin/slamd" --help | grep -qF "$data/web" || fail "slamd --help does not default --web-root to $data/web"

get() {  # get PORT PATH: the whole HTTP response, through bash's /dev/tcp
  exec 3<> "/dev/tcp/127.0.0.1/$1"
  printf 'GET %s HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n' "$2" >&3
  cat <&3
  exec 3<&-
}
# Created first: the background job opens them when it is scheduled, maybe after the first read.
: > "$work/slamd.out"
: > "$work/slamd.err"
"$bin/slamd" --port 0 --foxglove-port 0 --quiet > "$work/slamd.out" 2> "$work/slamd.err" &
slamd_pid=$!
trap 'kill "$slamd_pid" 2> /dev/null || true' EXIT
port=
for _ in $(seq 100); do
  port=$(sed -n 's|^slamd: serving http://127.0.0.1:\([0-9]*\)/.*|\1|p' "$work/slamd.out")
  [[ -n $port ]] && break
  kill -0 "$slamd_pid" 2> /dev/null || { cat "$work/slamd.err"; fail "the unpacked slamd exited"; }
  sleep 0.1
done
[[ -n $port ]] || fail "the unpacked slamd printed no URL within 10 s"
get "$port" /api/v1/health | grep -q '{"status":"ok"}' || fail "GET /api/v1/health"
get "$port" /vendor/uplot/uPlot.iife.min.js | grep -q '^HTTP/1.1 200' || fail "GET the page's uPlot"
kill -TERM "$slamd_pid"
wait "$slamd_pid" || fail "the unpacked slamd exited with status $? on SIGTERM"
trap - EXIT
echo "the unpacked slamd: its robot and page, /api/v1/health answers, SIGTERM exits 0"
echo "PASS"
