#!/usr/bin/env bash
# The slamd page in real Chromium: starts SLAMD_BIN on a free port with the page of this source
# tree, waits for it, runs e2e.mjs against it and always stops it.
#
#   tests/browser/run-e2e.sh SLAMD_BIN ARTIFACT_DIR
#
# Exit 0 pass, 77 skip (no /usr/bin/chromium or no web/node_modules/playwright-core), else fail.
set -euo pipefail

if [[ $# -ne 2 ]]; then
  echo "usage: $0 SLAMD_BIN ARTIFACT_DIR" >&2
  exit 2
fi
slamd_bin=$1
artifact_dir=$2
here=$(cd "$(dirname "$0")" && pwd)
web_root=$(cd "$here/../../web" && pwd)

if [[ ! -x /usr/bin/chromium ]]; then
  echo "SKIP: /usr/bin/chromium is missing (apt-get install chromium)"
  exit 77
fi
if [[ ! -d $web_root/node_modules/playwright-core ]] || ! command -v node > /dev/null; then
  echo "SKIP: node or $web_root/node_modules/playwright-core is missing (npm ci --prefix web)"
  exit 77
fi
if [[ ! -x $slamd_bin ]]; then
  echo "FAIL: $slamd_bin is not an executable" >&2
  exit 1
fi

mkdir -p "$artifact_dir"
artifact_dir=$(cd "$artifact_dir" && pwd)
stdout_log=$artifact_dir/slamd.stdout
stderr_log=$artifact_dir/slamd.stderr

# Created first: the background job opens them when it is scheduled, maybe after the first read
# (a missing file fails sed, and set -e the script).
: > "$stdout_log"
: > "$stderr_log"
"$slamd_bin" --port 0 --foxglove-port 0 --speed 4 --quiet --web-root "$web_root" > "$stdout_log" 2> "$stderr_log" &
slamd_pid=$!

stop_slamd() {
  if kill -0 "$slamd_pid" 2> /dev/null; then
    kill -TERM "$slamd_pid" 2> /dev/null || true
    for _ in $(seq 50); do  # up to 5 s for a clean exit
      kill -0 "$slamd_pid" 2> /dev/null || break
      sleep 0.1
    done
    if kill -0 "$slamd_pid" 2> /dev/null; then
      echo "slamd did not stop on SIGTERM within 5 s: killing it" >&2
      kill -KILL "$slamd_pid" 2> /dev/null || true
    fi
  fi
  wait "$slamd_pid" 2> /dev/null || true
}
trap stop_slamd EXIT

fail() {
  echo "FAIL: $*" >&2
  echo "--- slamd stderr (last lines) ---" >&2
  tail -n 20 "$stderr_log" >&2 || true
  exit 1
}

# The URL from "slamd: serving http://127.0.0.1:PORT/ (source ...)", within 20 s.
url=
for _ in $(seq 200); do
  url=$(sed -n 's|^slamd: serving \(http://[^ ]*\).*|\1|p' "$stdout_log" | head -n 1)
  [[ -n $url ]] && break
  kill -0 "$slamd_pid" 2> /dev/null || fail "slamd exited before serving"
  sleep 0.1
done
[[ -n $url ]] || fail "slamd printed no 'slamd: serving' line within 20 s"

# /api/v1/health, within 10 s.
healthy=
for _ in $(seq 50); do
  if timeout 2 node -e 'fetch(process.argv[1]).then((r) => process.exit(r.ok ? 0 : 1),
                                                     () => process.exit(1))' \
       "${url%/}/api/v1/health" 2> /dev/null; then
    healthy=1
    break
  fi
  kill -0 "$slamd_pid" 2> /dev/null || fail "slamd exited before it was healthy"
  sleep 0.2
done
[[ -n $healthy ]] || fail "$url/api/v1/health did not answer 200 within 10 s"

echo "slamd at $url (pid $slamd_pid)"
status=0
SLAMD_BIN=$slamd_bin WEB_ROOT=$web_root \
  timeout --kill-after=5 150 node "$here/e2e.mjs" "$url" "$artifact_dir" || status=$?
if [[ $status -eq 124 ]]; then
  fail "e2e.mjs timed out after 150 s"
elif [[ $status -ne 0 ]]; then
  fail "e2e.mjs failed (exit $status)"
fi
kill -0 "$slamd_pid" 2> /dev/null || fail "slamd died during the test"

# `?static`: Chromium's own headless screenshot of the page finishes (with a virtual time budget,
# the page's event stream used to keep it waiting until killed).
shot=$artifact_dir/slamd-page-static.png
profile=$(mktemp -d)
rm -f "$shot"
timeout --kill-after=5 60 /usr/bin/chromium --headless --no-sandbox --disable-gpu --disable-quic \
  --no-first-run --disable-background-networking --disable-component-update --disable-sync \
  --user-data-dir="$profile" --window-size=1400,950 --virtual-time-budget=5000 \
  --screenshot="$shot" "${url%/}/?static" > /dev/null 2>&1 || status=$?
rm -rf "$profile"
[[ $status -eq 0 ]] || fail "chromium --screenshot of ${url%/}/?static did not finish (exit $status)"
[[ -s $shot ]] || fail "chromium --screenshot of ${url%/}/?static wrote no picture"
echo "a headless screenshot of ?static: $shot"
echo "PASS: browser e2e"
