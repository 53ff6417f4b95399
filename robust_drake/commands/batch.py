"""``robust-drake batch SPEC --out results.parquet``: many closed loops, in parallel, resumable."""

from __future__ import annotations

import math
import sys

from robust_drake.cli import add_output_flags, format_table, print_json, show_progress
from robust_drake.errors import RobustDrakeError


def register(sub):
    p = sub.add_parser(
        "batch", help="run a batch of closed loops (YAML/CSV spec) in parallel into Parquet",
        description=(
            "Run every scenario of SPEC (YAML product/list spec or CSV, see "
            "robust_drake.scenario) in local worker processes or on a Dask cluster, writing one "
            "row per scenario to a Parquet file as it finishes. Rerunning the same command "
            "skips finished scenarios; a file of another spec is never overwritten without "
            "--force."))
    p.add_argument("spec", help="batch spec (.yaml/.yml/.json or .csv)")
    p.add_argument("--out", required=True, help="results file (.parquet)")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: the core count; 1 = in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address, e.g. tcp://10.0.0.5:8786 (overrides --workers)")
    p.add_argument("--force", action="store_true",
                   help="overwrite OUT even if it holds results of another spec, and rerun all")
    p.add_argument("--retry-failed", action="store_true",
                   help="rerun scenarios recorded as failed (diverged runs are kept)")
    p.add_argument("--duration", type=float, default=None,
                   help="override every scenario's simulated time [s] (quick trials)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (as -q)")
    p.add_argument("--no-reuse", action="store_true",
                   help="build a fresh diagram for every scenario (default: reuse per worker)")
    p.add_argument("--metric", default=None,
                   help="metric summarised per controller (default maxerr_task; for arms other than planar "
                        "2-link ones, where it is undefined, maxerr_joints: the largest joint error [rad])")
    add_output_flags(p, plot=None)
    p.set_defaults(func=run)


def run(args) -> int:
    from robust_drake.batch import METRIC_KEYS, run_batch, summarize
    from robust_drake.scenario import load_spec

    if args.metric is not None and args.metric not in (*METRIC_KEYS, "maxerr_joints"):
        raise RobustDrakeError(f"--metric must be one of {', '.join(METRIC_KEYS)}, maxerr_joints")
    if args.workers is not None and args.workers < 1:
        raise RobustDrakeError("--workers must be >= 1")
    if not args.out.strip():
        raise RobustDrakeError("--out is empty; give a results file path ending in .parquet")
    scenarios, doc = load_spec(args.spec)
    if args.duration is not None:
        if not args.duration > 0:
            raise RobustDrakeError("--duration must be positive")
        for s in scenarios:
            s.duration = float(args.duration)
        doc = {"spec": doc, "duration_override": args.duration}
    if not scenarios:
        raise RobustDrakeError(f"{args.spec} defines no scenarios")
    if not args.json:
        where = f"Dask at {args.scheduler}" if args.scheduler else (
            f"{args.workers or 'all'} local worker(s)")
        print(f"{len(scenarios)} scenarios from {args.spec} -> {args.out} ({where})",
              file=sys.stderr)
    try:
        df = run_batch(scenarios, out=args.out, workers=args.workers, scheduler=args.scheduler,
                       force=args.force, retry_failed=args.retry_failed,
                       progress=not args.no_progress and show_progress(args),
                       reuse=not args.no_reuse, spec=doc)
    except KeyboardInterrupt:
        print(f"interrupted: finished scenarios are saved in {args.out}; rerun the same command "
              "to continue", file=sys.stderr)
        raise
    counts = {s: int((df["status"] == s).sum()) for s in ("ok", "diverged", "failed")}
    metric, note = _summary_metric(df, args.metric)
    if note:
        print(f"note: {note}", file=sys.stderr)
    summary = summarize(df, by=("controller",), metric=metric)
    if args.json:
        print_json({
            "out": args.out, "fingerprint": df.attrs["fingerprint"], "scenarios": len(df),
            "ran": df.attrs["ran"], "skipped": df.attrs["skipped"],
            "wall_seconds": df.attrs["wall_seconds"], "status_counts": counts,
            "metric": metric, **({"metric_note": note} if note else {}),
            "summary": [{k: (None if isinstance(v, float) and math.isnan(v) else v)
                         for k, v in r.items()} for r in summary.to_dict("records")],
            "failures": [{"scenario_id": r["scenario_id"], "name": r["name"],
                          "status": r["status"], "error": r["error"]}
                         for r in df[df["status"] != "ok"].to_dict("records")],
        })
    else:
        print(f"{len(df)} scenarios: {counts['ok']} ok, {counts['diverged']} diverged, "
              f"{counts['failed']} failed ({df.attrs['ran']} run now, {df.attrs['skipped']} "
              f"already in {args.out}; {df.attrs['wall_seconds']:.1f} s)")
        if len(summary):
            cols = ["controller", "runs", "ok", "diverged", "failed", "p50", "p90", "worst"]
            print(f"{metric} over ok runs:")
            print(format_table([[r[c] for c in cols] for r in summary.to_dict("records")], cols))
        bad = df[df["status"] != "ok"]
        for r in bad.head(10).to_dict("records"):
            print(f"  {r['status']}: {r['name']}: {r['error']}")
        if len(bad) > 10:
            print(f"  ... {len(bad) - 10} more (see the 'error' column)")
    return 0 if counts["failed"] == 0 else 1


def _summary_metric(df, asked: str | None) -> tuple[str, str | None]:
    """The metric the summary shows and a note: ``maxerr_task`` by default, ``maxerr_joints`` (the
    largest joint error, added to ``df``) where the task-space criteria are undefined (NaN on every
    ok run: arms other than planar 2-link ones); a metric asked for that is NaN on every ok run
    gets a note instead of a table of nan."""
    import re

    ok = df["status"] == "ok" if "status" in df else None
    joint_cols = [c for c in df.columns if re.fullmatch(r"maxerr\d+", str(c))]
    if joint_cols and "maxerr_joints" not in df:  # results written before the column existed
        df["maxerr_joints"] = df[joint_cols].astype(float).max(axis=1)
    metric = asked or "maxerr_task"
    if ok is None or not ok.any() or metric not in df:
        return metric, None
    if df.loc[ok, metric].astype(float).notna().any():
        return metric, None
    if asked is None and joint_cols:
        return "maxerr_joints", ("maxerr_task (JS eq. 59) is defined only for planar 2-link arms: the summary shows "
                                 "maxerr_joints, the largest joint error [rad]")
    return metric, f"{metric} is undefined (NaN) on every ok run; choose another --metric"
