#!/usr/bin/env bash
# slamd's Foxglove WebSocket server with the official client: starts SLAMD_BIN twice on free
# ports (on loopback without a token, then with a token file and a 64 KiB client buffer), runs
# foxglove.mjs against each and always stops them.
#
#   tests/foxglove/run-foxglove.sh SLAMD_BIN WORK_DIR
#
# Exit 0 pass, 77 skip (no node or no web/node_modules/@foxglove/ws-protocol), else fail.
set -euo pipefail

if [[ $# -ne 2 ]]; then
  echo "usage: $0 SLAMD_BIN WORK_DIR" >&2
  exit 2
fi
slamd_bin=$1
work_dir=$2
here=$(cd "$(dirname "$0")" && pwd)
web_root=$(cd "$here/../../web" && pwd)

if ! command -v node > /dev/null || [[ ! -d $web_root/node_modules/@foxglove/ws-protocol ]]; then
  echo "SKIP: node or $web_root/node_modules/@foxglove/ws-protocol is missing (npm ci --prefix web)"
  exit 77
fi
if [[ ! -x $slamd_bin ]]; then
  echo "FAIL: $slamd_bin is not an executable" >&2
  exit 1
fi
mkdir -p "$work_dir"
work_dir=$(cd "$work_dir" && pwd)

pids=()
stop_all() {
  for pid in "${pids[@]}"; do
    kill -TERM "$pid" 2> /dev/null || true
  done
  for pid in "${pids[@]}"; do
    for _ in $(seq 50); do  # up to 5 s for a clean exit
      kill -0 "$pid" 2> /dev/null || break
      sleep 0.1
    done
    kill -KILL "$pid" 2> /dev/null || true
    wait "$pid" 2> /dev/null || true
  done
}
trap stop_all EXIT

fail() {
  echo "FAIL: $*" >&2
  for log in "$work_dir"/*.stderr; do
    echo "--- $log (last lines) ---" >&2
    tail -n 20 "$log" >&2 || true
  done
  exit 1
}

# Starts slamd NAME ARGS...; sets http_url and ws_url from its start lines (within 20 s).
start() {
  local name=$1
  shift
  # --foxglove-port 0 turns the server off: a port free now (another process could take it
  # before slamd binds it; slamd then exits, and this fails, naming it).
  local port
  port=$(node -e 'const s = require("net").createServer().listen(0, "127.0.0.1", () => {
                    console.log(s.address().port); s.close(); });')
  # Created first: the background job opens them when it is scheduled, maybe after the first
  # read (a missing file fails sed, and set -e the script).
  : > "$work_dir/$name.stdout"
  : > "$work_dir/$name.stderr"
  "$slamd_bin" --port 0 --foxglove-port "$port" --speed 4 --quiet "$@" \
    > "$work_dir/$name.stdout" 2> "$work_dir/$name.stderr" &
  local pid=$!
  pids+=("$pid")
  http_url= ws_url=
  for _ in $(seq 200); do
    http_url=$(sed -n 's|^slamd: serving \(http://[^ ]*\).*|\1|p' "$work_dir/$name.stdout" | head -n 1)
    ws_url=$(sed -n 's|^slamd: Foxglove WebSocket on \(ws://[^ ]*\).*|\1|p' "$work_dir/$name.stdout" | head -n 1)
    [[ -n $http_url && -n $ws_url ]] && return 0
    kill -0 "$pid" 2> /dev/null || fail "slamd ($name) exited before serving"
    sleep 0.1
  done
  fail "slamd ($name) printed no serving lines within 20 s"
}

run() {
  local status=0
  timeout --kill-after=5 120 node "$here/foxglove.mjs" "$@" || status=$?
  [[ $status -eq 124 ]] && fail "foxglove.mjs $1 timed out after 120 s"
  [[ $status -ne 0 ]] && fail "foxglove.mjs $1 failed (exit $status)"
  return 0
}

start open
echo "slamd (open) at $http_url, Foxglove at $ws_url"
run open "$http_url" "$ws_url"

token=foxglove-test-token-$RANDOM$RANDOM
printf '%s\n' "$token" > "$work_dir/token"
start token --token-file "$work_dir/token" --foxglove-buffer-kb 64
echo "slamd (token) at $http_url, Foxglove at $ws_url"
run token "$http_url" "$ws_url" "$token"

for pid in "${pids[@]}"; do
  kill -0 "$pid" 2> /dev/null || fail "a slamd died during the test"
done
echo "PASS: Foxglove clients"
