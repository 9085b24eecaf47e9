#!/usr/bin/env bash
# slam-tune under MPI against one process (issue 24): a small study under
# `mpirun --oversubscribe -np 3` gives the results.json of the one-process study ("ranks" aside),
# and a study started with 3 ranks and extended by one process (or the other way round) is the
# one-process study that took the same steps.
#   run-mpi-tune.sh SLAM_SIM SLAM_TUNE WORKDIR
# Exits 77 (skipped) when slam-tune was built without MPI or mpirun is missing.
set -euo pipefail
sim=$1 tune=$2 work=$3
if ! command -v mpirun >/dev/null 2>&1; then
  echo "mpirun not found (scripts/deps installs openmpi-bin): skipped" >&2
  exit 77
fi
if ! ldd "$tune" | grep libmpi >/dev/null; then
  echo "slam-tune was built without MPI (scripts/deps installs libopenmpi-dev): skipped" >&2
  exit 77
fi
rm -rf "$work"
mkdir -p "$work"
"$sim" dataset --set training --runs 1 --duration 30 --out "$work/exp" >/dev/null 2>&1

mpi=(mpirun --oversubscribe --mca btl self,vader --mca btl_vader_single_copy_mechanism none)
if [[ $(id -u) == 0 ]]; then
  mpi+=(--allow-run-as-root)
fi
study=("$tune" --experiments "$work/exp/box-1001" "$work/exp/rooms-1001" "$work/exp/flat-1001"
  --budgets 2000,4000 --population 10 --quiet)

same() {  # same A B: the two results.json equal but for "ranks"
  python3 - "$1" "$2" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
ranks = (a.pop("ranks"), b.pop("ranks"))
if a != b:
    sys.exit(f"{sys.argv[1]} and {sys.argv[2]} differ")
spared = sum(g["cost"]["replays_saved"] for run in a["budgets"] for g in run["generations"])
print(f"same study with {ranks[0]} and {ranks[1]} ranks ({spared} replays spared by racing)")
PY
}
ranks() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["ranks"])' "$1"; }

"${study[@]}" --generations 4 --out "$work/one" >/dev/null
"${mpi[@]}" -np 3 "${study[@]}" --generations 4 --out "$work/three" >/dev/null
[[ $(ranks "$work/one/results.json") == 1 && $(ranks "$work/three/results.json") == 3 ]]
same "$work/one/results.json" "$work/three/results.json"

# Resumed across rank counts: two generations, then extended to four (a study of two evaluates
# its second whole, so it is compared with the same two steps in one process).
"${study[@]}" --generations 2 --out "$work/steps" >/dev/null
"${study[@]}" --generations 4 --out "$work/steps" >/dev/null
"${mpi[@]}" -np 3 "${study[@]}" --generations 2 --out "$work/resumed" >/dev/null
"${study[@]}" --generations 4 --out "$work/resumed" >/dev/null
same "$work/steps/results.json" "$work/resumed/results.json"
"${study[@]}" --generations 2 --out "$work/resumed2" >/dev/null
"${mpi[@]}" -np 2 "${study[@]}" --generations 4 --out "$work/resumed2" >/dev/null
same "$work/steps/results.json" "$work/resumed2/results.json"
for f in table2.md table3.md params/2000.json params/4000.json; do
  cmp "$work/one/$f" "$work/three/$f"
done

# Only rank 0 reports: one error line, not three, for a bad argument.
lines=$("${mpi[@]}" -np 3 "$tune" --experiments "$work/nowhere" --out "$work/bad" 2>&1 | grep -c "slam-tune:" || true)
[[ $lines == 1 ]] || { echo "expected one error line from 3 ranks, got $lines" >&2; exit 1; }
rm -rf "$work"
echo "run-mpi-tune.sh: passed"
