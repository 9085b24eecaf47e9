#!/usr/bin/env bash
# Outside clients in the tests (issue 26): programs somebody else wrote read what ours write.
#
#   tests/outside/run.sh promtool         SLAMD WORK_DIR      promtool check metrics on /metrics
#   tests/outside/run.sh python-can-log   SLAM_SIM SLAM_LINK WORK_DIR
#                                         python-can's CanutilsLogReader on slam-sim's can.log
#   tests/outside/run.sh python-can-slcan SLAMD SLAM_SIM WORK_DIR
#                                         python-can's slcan bus feeding slamd's slcan source
#   tests/outside/run.sh log2asc          SLAM_SIM WORK_DIR   can-utils' log2asc on can.log
#
# Exit 0 pass, 77 skip (only when the outside client is not installed: `scripts/deps --test`
# installs prometheus, python3-can, python3-serial and can-utils), anything else fail. The
# checks are Python scripts beside this one, run by Debian's python3 (/usr/bin/python3), whose
# dist-packages hold python3-can: another python3 first on PATH (pyenv, a venv) would not see it.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)

if [[ $# -lt 1 ]]; then
  sed -n '4,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 2
fi
test_name=$1
shift

python=/usr/bin/python3
if [[ ! -x $python ]]; then
  python=$(command -v python3 || true)
  if [[ -z $python ]]; then
    echo "FAIL: no python3 (scripts/deps installs Debian's python3)" >&2
    exit 1
  fi
fi

# No __pycache__ in the source tree.
export PYTHONDONTWRITEBYTECODE=1

skip() {
  echo "SKIP: $*"
  exit 77
}
need_tool() {  # need_tool PROGRAM PACKAGE
  command -v "$1" > /dev/null || skip "$1 is missing (apt-get install $2)"
}
need_module() {  # need_module MODULE PACKAGE
  "$python" -c "import $1" 2> /dev/null || skip "$python cannot import $1 (apt-get install $2)"
}

case "$test_name" in
  promtool)
    [[ $# -eq 2 ]] || { echo "usage: $0 promtool SLAMD WORK_DIR" >&2; exit 2; }
    need_tool promtool prometheus
    exec "$python" "$here/promtool_metrics.py" "$(command -v promtool)" "$@"
    ;;
  python-can-log)
    [[ $# -eq 3 ]] || { echo "usage: $0 python-can-log SLAM_SIM SLAM_LINK WORK_DIR" >&2; exit 2; }
    need_module can python3-can
    exec "$python" "$here/python_can_log.py" "$@"
    ;;
  python-can-slcan)
    [[ $# -eq 3 ]] || { echo "usage: $0 python-can-slcan SLAMD SLAM_SIM WORK_DIR" >&2; exit 2; }
    need_module can python3-can
    need_module serial python3-serial
    exec "$python" "$here/python_can_slcan.py" "$@"
    ;;
  log2asc)
    [[ $# -eq 2 ]] || { echo "usage: $0 log2asc SLAM_SIM WORK_DIR" >&2; exit 2; }
    need_tool log2asc can-utils
    exec "$python" "$here/log2asc_log.py" "$(command -v log2asc)" "$@"
    ;;
  *)
    echo "$0: unknown test '$test_name' (promtool, python-can-log, python-can-slcan, log2asc)" >&2
    exit 2
    ;;
esac
