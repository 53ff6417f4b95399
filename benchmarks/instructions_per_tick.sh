#!/usr/bin/env bash
# Instructions per 2500 Hz tick of each row of bench_closed_loop.py's D2R2 table, counted by valgrind's
# callgrind inside Simulator::AdvanceTo only (model building and Python start-up excluded). Unlike
# process time, the count does not change with other load on the machine, so block costs and the
# loop/plant ratio can be compared between runs and machines. Needs valgrind; ~40 s per row on a quiet
# machine (4 min on a loaded one: give ROWS, e.g. "6" for the full loop; row 0, the plant alone, always runs).
#
#   OPENBLAS_NUM_THREADS=1 PYTHONPATH=. bash benchmarks/instructions_per_tick.sh [seconds=0.4] [python] [ROWS=all]
set -euo pipefail
secs=${1:-0.4}
py=${2:-python}
sel=${3:-all}
command -v valgrind >/dev/null || { echo "error: valgrind is not installed" >&2; exit 2; }
here=$(cd "$(dirname "$0")" && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
ticks=$("$py" -c "print(round($secs * 2500))")
rows=$("$py" -c "import sys; sys.path.insert(0, '$here'); import bench_closed_loop as b; print(len(b.d2r2_rows(0.1)[1]))")
printf '%-58s %12s %8s\n' "configuration (instructions per tick)" "instr/tick" "x plant"
base=""
for ((i = 0; i < rows; i++)); do
  if [ "$sel" != all ] && [ "$i" != 0 ] && ! [[ ",$sel," == *",$i,"* ]]; then continue; fi
  name=$(valgrind --tool=callgrind --toggle-collect='drake::systems::Simulator<double>::AdvanceTo*' \
           --callgrind-out-file="$tmp/cg.$i" "$py" "$here/bench_closed_loop.py" --part d2r2 --row "$i" \
           --seconds "$secs" 2>"$tmp/err.$i" | head -1)
  n=$(grep -o 'Collected : [0-9]*' "$tmp/err.$i" | awk '{print $3}')
  per=$((n / ticks))
  [ -z "$base" ] && base=$per
  printf '%-58s %12d %8s\n' "$name" "$per" "$("$py" -c "print(f'{$per / $base:.2f}')")"
done
