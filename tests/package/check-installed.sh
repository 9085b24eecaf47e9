#!/usr/bin/env bash
# Runs as root inside a fresh Debian 12 root (scripts/fresh-debian --deb): installs the package
# in /tmp with apt-get, which must fetch its libraries from Debian's archive, then checks the
# installed programs as a user would meet them. No systemd runs in a chroot, so slamd is started
# by hand, as an unprivileged user, with the shipped defaults and a state directory.
set -euo pipefail

deb=$(ls /tmp/slamd_*.deb)
export DEBIAN_FRONTEND=noninteractive
apt-get update -q
apt-get install -y -q --no-install-recommends "$deb"
echo "installed: $(dpkg-query -W -f='${Package} ${Version} ${db:Status-Status}' slamd)"
version=$(dpkg-query -W -f='${Version}' slamd)

for program in slamd slam-sim slam-link slam-replay slam-evaluate slam-relations slam-tune slamd-load; do
  printed=$("$program" --version)
  [[ $printed == "$program $version" ]] || { echo "$program --version printed '$printed'"; exit 1; }
done
echo "every program's --version: $version"
[[ -f /etc/default/slamd && -f /lib/systemd/system/slamd.service ]]
[[ -L /etc/systemd/system/multi-user.target.wants/slamd.service ]] ||
  { echo "postinst did not enable slamd.service"; exit 1; }
echo "slamd.service is enabled (postinst)"

get() {  # get PORT PATH: the whole HTTP response, through bash's /dev/tcp
  exec 3<> "/dev/tcp/127.0.0.1/$1"
  printf 'GET %s HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n' "$2" >&3
  cat <&3
  exec 3<&-
}

mkdir -p /tmp/state
chown nobody:nogroup /tmp/state
cd /tmp
# Created before slamd starts: the background job opens them when it is scheduled, which on a
# loaded machine can come after the first read below (a missing file fails sed, and set -e the
# script).
: > /tmp/slamd.out
: > /tmp/slamd.err
setpriv --reuid=nobody --regid=nogroup --clear-groups \
  slamd --port 0 --foxglove-port 0 --state-dir /tmp/state > /tmp/slamd.out 2> /tmp/slamd.err &
slamd_pid=$!
port=
for _ in $(seq 100); do
  port=$(sed -n 's|^slamd: serving http://127.0.0.1:\([0-9]*\)/.*|\1|p' /tmp/slamd.out)
  [[ -n $port ]] && break
  kill -0 "$slamd_pid" 2> /dev/null || { echo "slamd exited:"; cat /tmp/slamd.err; exit 1; }
  sleep 0.1
done
[[ -n $port ]] || { echo "slamd printed no URL within 10 s"; cat /tmp/slamd.err; exit 1; }
echo "slamd serves on port $port: $(head -n 1 /tmp/slamd.out)"

health=$(get "$port" /api/v1/health)
if ! grep -q '^HTTP/1.1 200' <<< "$health" || ! grep -q '{"status":"ok"}' <<< "$health"; then
  echo "GET /api/v1/health answered:"
  echo "$health"
  exit 1
fi
echo "GET /api/v1/health: $(tail -n 1 <<< "$health")"
get "$port" / | grep -q '<html' || { echo "GET / gave no page"; exit 1; }
get "$port" /vendor/uplot/uPlot.iife.min.js | grep -q '^HTTP/1.1 200' ||
  { echo "GET /vendor/uplot/uPlot.iife.min.js failed: the page would have no plots"; exit 1; }
echo "GET / and the page's uPlot: 200"

sleep 3  # a few scans
kill -TERM "$slamd_pid"
status=0
wait "$slamd_pid" || status=$?
if ((status != 0)) || [[ ! -f /tmp/state/state.json ]]; then
  echo "slamd exited with status $status on SIGTERM; state.json saved: $([[ -f /tmp/state/state.json ]] && echo yes || echo no)"
  cat /tmp/slamd.err
  exit 1
fi
echo "SIGTERM: slamd saved the map ($(ls /tmp/state | tr '\n' ' ')) and exited with status 0"

apt-get purge -y -q slamd > /dev/null
if [[ $(dpkg-query -W -f='${db:Status-Status}' slamd 2> /dev/null || true) == installed ]]; then
  echo "apt-get purge left slamd installed"
  exit 1
fi
for path in /usr/bin/slamd /usr/share/slamd /etc/default/slamd \
  /etc/systemd/system/multi-user.target.wants/slamd.service; do
  [[ ! -e $path && ! -L $path ]] || { echo "apt-get purge left $path behind"; exit 1; }
done
echo "apt-get purge slamd: nothing left behind"
