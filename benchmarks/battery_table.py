"""Run the issue-13 battery (robust_drake.synthetic.battery) and print its table.

Usage (from the repository root):
    OPENBLAS_NUM_THREADS=1 python benchmarks/battery_table.py [--arms siciliano_2link,...]
        [--cases none,spring,...] [--json rows.json]
Prints a markdown table (arm, case, truth, claimed effects, parameter error, validation RMS per
joint before -> after, never-worse, time) and the total time.
"""

import argparse
import json
import sys
import tempfile
import time

from robust_drake.synthetic import battery as B


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default=",".join(B.BATTERY_ARMS))
    ap.add_argument("--cases", default=None, help="comma-separated (default: battery.CASES of each arm)")
    ap.add_argument("--json", default=None, help="also write the rows here")
    ap.add_argument("--no-replay", action="store_true")
    a = ap.parse_args(argv)
    rows, t0 = [], time.perf_counter()
    out = tempfile.mkdtemp(prefix="battery_")
    for arm in a.arms.split(","):
        for case in (a.cases.split(",") if a.cases else B.CASES[arm]):
            try:
                row = B.run_case(arm, case, f"{out}/{arm}/{case}", replay=not a.no_replay)
            except Exception as exc:  # a crash is a result of the battery too
                print(f"{arm} {case}: {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            rows.append(row)
            print(B.format_table([row]).splitlines()[-1], flush=True)
    print()
    print(B.format_table(rows))
    print(f"\n{len(rows)} cases in {time.perf_counter() - t0:.0f} s")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
