"""Calibration of the repair's decisions on six- and seven-axis arms (issue 21).

1. False acceptance: on no-effect data (``arm_battery.generate(arm, "none", seed=s)``, one fit and
   one validation run of DURATION s at RATE Hz, current-based torque noise), the share of seeds
   on which the repair accepts ANY effect, with its Clopper-Pearson 95 % interval, beside the
   stated level 1 - ``decisions.LEVEL`` (5 %).
2. Detection: per library kind (``arm_battery.LINEAR_KINDS``) at 3x and 10x the joint's noise
   RMS (``arm_battery.library_case``), the share of seeds on which that kind is named on its
   joint, and the share with the key parameter within 10 %.

The repair runs with ``replay=False, plots=False``: the replay guard is not what this
benchmark calibrates (it costs most of a 6-axis repair's time), and ``consistent=False`` as the
issue-13 battery.  Each repair is timed; the largest 6-axis case's time is printed.

Usage (from the repository root):
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/calibration.py [--arms ur5,serial7]
        [--seeds 30] [--first-seed 0] [--detect-seeds 3] [--jobs 1] [--quick] [--rate 500] [--duration 10]
        [--part all|fa|detect] [--detect-arms ur5] [--out benchmarks/calibration_table.md]
        [--jsonl rows.jsonl] [--tables-from a.jsonl,b.jsonl]
``--quick``: 3 seeds and 1 detection seed (a smoke test).  The table is written as markdown to
``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of k successes in n trials at ``level``."""
    from scipy.stats import beta

    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def run_one(item: dict) -> dict:
    """Generate and repair one (arm, case / kind, level, seed) item; the scored row."""
    from robust_drake.errors import RobustDrakeError
    from robust_drake.synthetic import arm_battery as AB
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    out = tempfile.mkdtemp(prefix="calib_")
    kw = dict(out_dir=out, rate_hz=item["rate"], duration=item["duration"], seed=item["seed"])
    if item.get("case"):
        return _battery_row(item, AB.generate(item["arm"], item["case"], **kw))
    if item["kind"] is None:
        fits, vals, truth = AB.generate(item["arm"], "none", **kw)
    else:
        try:
            fits, vals, truth = AB.library_case(item["arm"], item["kind"], item["level"], **kw)
        except RobustDrakeError as exc:  # a magnitude beyond the kind's physical bound
            return {**item, "skipped": str(exc), "t_repair": 0.0, "claimed": []}
        truth["effects"] = [(truth["kind"], truth["joint"], truth["parameters"])]
    t0 = time.perf_counter()
    rep = run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                     validate_paths=vals)
    row = {**item, "t_repair": time.perf_counter() - t0, "claimed": AB.claimed(rep), "verdict": rep["verdict"]}
    if item["kind"] is not None:
        mt = AB.matches(rep, truth)
        m = mt["effects"][0]
        # named = kept AND claimed (an effect kept under a flagged setup change is not claimed)
        named = m["found"] and any(c[0] == truth["kind"] and (truth["joint"] is None or c[1] == truth["joint"])
                                   for c in row["claimed"])
        row.update(joint=truth["joint"], found=named, rel_error=m["rel_error"] if named else None, true=m["true"],
                   estimate=m["estimate"], others=len(mt["others"]))
    return row


def _battery_row(item, generated) -> dict:
    """Repair one battery case (``arm_battery.generate``) and score it against its truth."""
    from robust_drake.synthetic import arm_battery as AB
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    fits, vals, truth = generated
    t0 = time.perf_counter()
    rep = run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                     validate_paths=vals)
    m = AB.matches(rep, truth)
    before, after = (np.asarray(rep[k]["rms_validate"], float) for k in ("baseline", "final"))
    return {**item, "t_repair": time.perf_counter() - t0, "claimed": AB.claimed(rep), "verdict": rep["verdict"],
            "truth": [f"{k}[{'all' if j is None else j}]" for k, j, _ in truth.get("effects", [])]
            or [truth.get("setup_change") or "none"],
            "named": [(e["kind"], e["found"], e["rel_error"]) for e in m["effects"]], "others": m["others"],
            "flagged": bool(rep["unexplained_structure"]), "never_worse": bool(np.all(after <= before * 1.01)),
            "before": before.tolist(), "after": after.tolist()}


def battery_table(rows) -> list[str]:
    lines = ["| arm | rate [Hz] | case | truth | claimed | named within 10 % | others claimed | "
             "unexplained flagged | never worse (1 %) | repair [s] |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if not r.get("case"):
            continue
        named = "; ".join(f"{k}: {'yes' if f and e is not None and e <= 0.1 else ('named, err ' + f'{100 * e:.0f} %' if f and e is not None else 'no')}"
                          for k, f, e in r["named"]) or "-"
        claimed = ", ".join(f"{k}[{j}] {c}" for k, j, c in r["claimed"]) or "nothing"
        lines.append(f"| {r['arm']} | {r['rate']:g} | {r['case']} | {', '.join(r['truth'])} | {claimed} | {named} | "
                     f"{len(r['others'])} | {'yes' if r['flagged'] else 'no'} | {'yes' if r['never_worse'] else 'NO'} | "
                     f"{r['t_repair']:.1f} |")
    return lines


def _run(items, jobs, jsonl=None):
    """Run the items; each row is appended to ``jsonl`` (one JSON object a line) as it ends."""
    from robust_drake.parallel import run_parallel

    rows = []
    for o in run_parallel(run_one, items, workers=jobs, progress=False, stream=True):
        if o.ok:
            rows.append(o.value)
            r = o.value
            if jsonl:
                with open(jsonl, "a") as fh:
                    fh.write(json.dumps(r, default=str) + "\n")
            print(f"  {r['arm']} {r['kind'] or 'none'} {r.get('level') or ''} seed {r['seed']}: "
                  f"{r.get('skipped') or ''}claimed {r['claimed']} found {r.get('found')} "
                  f"err {r.get('rel_error')} ({r['t_repair']:.1f} s)", flush=True)
        else:
            print(f"  failed: {o.error}", file=sys.stderr, flush=True)
    return rows


def fa_table(rows, arms, level) -> list[str]:
    lines = ["| arm | rate [Hz] | run [s] | seeds | any effect accepted | rate | 95 % interval (Clopper-Pearson) | "
             "stated level | what was accepted | median repair [s] |", "|---|---|---|---|---|---|---|---|---|---|"]
    for arm in arms:
        for rate in sorted({r["rate"] for r in rows if r["arm"] == arm}, reverse=True):
            rs = [r for r in rows if r["arm"] == arm and r["rate"] == rate and r["kind"] is None and not r.get("case")]
            if not rs:
                continue
            k = sum(bool(r["claimed"]) for r in rs)
            lo, hi = clopper_pearson(k, len(rs))
            what = "; ".join(sorted({f"{c[0]}[{c[1]}]" for r in rs for c in r["claimed"]})) or "-"
            lines.append(f"| {arm} | {rate:g} | {rs[0]['duration']:g} | {len(rs)} | {k} | {k / len(rs):.1%} | "
                         f"[{lo:.1%}, {hi:.1%}] | {1 - level:.0%} | {what} | "
                         f"{np.median([r['t_repair'] for r in rs]):.1f} |")
    return lines


def detect_table(rows, arms) -> list[str]:
    lines = ["| arm | rate [Hz] | kind | joint | level (x noise RMS) | seeds | named | named, key within 10 % | "
             "median key error | false others |", "|---|---|---|---|---|---|---|---|---|---|"]
    for arm in arms:
        keys = sorted({(r["kind"], r["level"]) for r in rows if r["arm"] == arm and r["kind"]})
        for kind, lev in keys:
            rs = [r for r in rows if r["arm"] == arm and r["kind"] == kind and r["level"] == lev]
            skipped = [r for r in rs if r.get("skipped")]
            if skipped:
                lines.append(f"| {arm} | {rs[0]['rate']:g} | {kind} | - | {lev:g} | 0 | not generated: {skipped[0]['skipped']} | | | |")
                continue
            found = sum(r["found"] for r in rs)
            good = sum(bool(r["found"] and r["rel_error"] is not None and r["rel_error"] <= 0.10) for r in rs)
            errs = [r["rel_error"] for r in rs if r["rel_error"] is not None]
            others = sum(r.get("others", len(r["claimed"]) - int(r["found"])) for r in rs)
            lines.append(f"| {arm} | {rs[0]['rate']:g} | {kind} | {rs[0].get('joint', '-')} | {lev:g} | {len(rs)} | {found}/{len(rs)} | "
                         f"{good}/{len(rs)} | {'-' if not errs else f'{100 * np.median(errs):.0f} %'} | {others} |")
    return lines


def main(argv=None):
    from robust_drake.synthetic import arm_battery as AB
    from robust_drake.model_repair.decisions import LEVEL

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="ur5,serial7")
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--detect-seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0,
                    help="start of the seed range (no-effect seeds are 100 + first + s, detection 200 + first + s)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--rate", type=float, default=500.0)
    ap.add_argument("--duration", type=float, default=AB.DURATION)
    ap.add_argument("--part", choices=("all", "fa", "detect", "battery"), default="all")
    ap.add_argument("--rates", default="500,100", help="log rates [Hz] of the battery part")
    ap.add_argument("--kinds", default=",".join(AB.LINEAR_KINDS))
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "calibration_table.md"))
    ap.add_argument("--detect-arms", default=None, help="arms of the detection part (default: --arms)")
    ap.add_argument("--jsonl", default=None, help="append each row here as it ends")
    ap.add_argument("--tables-from", default=None, help="only rebuild the tables from these .jsonl files (comma-separated)")
    a = ap.parse_args(argv)
    seeds, dseeds = (3, 1) if a.quick else (a.seeds, a.detect_seeds)
    arms = a.arms.split(",")
    base = dict(rate=a.rate, duration=a.duration)
    items = []
    if a.part in ("all", "fa"):
        items += [dict(arm=arm, kind=None, level=None, seed=100 + a.first_seed + s, **base) for arm in arms for s in range(seeds)]
    if a.part in ("all", "detect"):
        items += [dict(arm=arm, kind=k, level=lev, seed=200 + a.first_seed + s, **base) for arm in (a.detect_arms or a.arms).split(",")
                  for k in a.kinds.split(",") for lev in (3.0, 10.0) for s in range(dseeds)]
    if a.part == "battery":
        items += [dict(arm=arm, kind=None, level=None, case=c, seed=0, rate=float(rt), duration=a.duration)
                  for arm in arms for rt in a.rates.split(",") for c in AB.CASES]
    t0 = time.perf_counter()
    if a.tables_from:
        rows = [json.loads(line) for f in a.tables_from.split(",") for line in open(f) if line.strip()]
        arms = list(dict.fromkeys(r["arm"] for r in rows))
    else:
        rows = _run(items, a.jobs, a.jsonl)
    for r in rows:  # the joint each detection item put its effect on (for the table)
        r.setdefault("joint", None)
    text = [f"# Repair calibration (benchmarks/calibration.py)", "",
            "Each case: one fit and one validation run (different motions) of the stated length and rate, current-based torque "
            f"noise (robust_drake/synthetic/arm_battery.py eq. 1); repair with replay and plots off, "
            f"consistent=False.  Detection: 'named' = the kind on its joint accepted.  Command: `{' '.join(['python benchmarks/calibration.py'] + (argv or sys.argv[1:]))}`", "",
            "## False acceptance on no-effect data", ""] + fa_table(rows, arms, LEVEL)
    text += ["", "## Detection per library kind", ""] + detect_table(rows, arms)
    if any(r.get("case") for r in rows):
        text += ["", "## The arm battery (arm_battery.CASES, seed 0)", ""] + battery_table(rows)
    six = [r for r in rows if r["arm"] == "ur5"]
    if six:
        big = max(six, key=lambda r: r["t_repair"])
        text += ["", f"Longest 6-axis repair: {big['t_repair']:.1f} s ({big.get('case') or big['kind'] or 'none'}, "
                     f"{big['rate']:g} Hz x {big['duration']:g} s, seed {big['seed']}); repair times add up to "
                     f"{sum(r['t_repair'] for r in rows):.0f} s over {len(rows)} items (wall "
                     f"{time.perf_counter() - t0:.0f} s this call; times on a shared 2-core machine)."]
    md = "\n".join(text) + "\n"
    print(md)
    with open(a.out, "w") as fh:
        fh.write(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
