"""The Jaritz & Spong experimental comparison on the simulated D2R2 (JS sections 8-11).

- :data:`TABLES`: which runs stand behind each of tables 2-7 (trajectory, load, friction
  compensation, epsilons), :data:`PUBLISHED`: the published numbers;
- :func:`table_runs` -> run specs, :func:`run_one` (module-level, picklable: one closed loop),
  :func:`run_table` (a table's runs in parallel with :func:`robust_drake.parallel.run_parallel`;
  a failed run becomes a row with ``error`` and NaN metrics, the others complete);
- :func:`format_paper_table`: the paper's layout with the published value beside each simulated one;
- :func:`plot_table`: the analogs of figures 4-11 (tracking errors and torques per controller);
- :func:`sweep_rate`: the sample-rate study proposed in section 11.

Row keys (``robust-drake compare --json`` contract): ``controller`` (``sp1``, ``sp2``, ``zc``,
``lgplus``), ``load`` (``none`` or ``max``), ``friction_compensation`` (bool) and the metric keys
``error1, maxerr1, error2, maxerr2, error_task, maxerr_task`` (JS eqs. 55, 56, 58, 59), plus
``table``, ``trajectory``, ``published`` (dict of the six values), ``diverged``,
``wall_seconds``, ``tau_tv_per_s`` and ``error`` (only when the run failed).
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.metrics import METRIC_KEYS

CONTROLLERS = ("sp1", "sp2", "zc", "lgplus")
LABELS = {"sp1": "SP1", "sp2": "SP2", "zc": "ZC", "lgplus": "LG+", "lg": "LG"}

#: Table number -> the experiment behind it (JS sections 9-10).
TABLES = {
    2: dict(trajectory="cpt", load="none", friction_compensation=False, title="CPT, no load"),
    3: dict(trajectory="cpt", load="max", friction_compensation=False, title="CPT, load"),
    4: dict(trajectory="cpt", load="none", friction_compensation=True, title="CPT with friction compensation, no load"),
    5: dict(trajectory="cpt", load="max", friction_compensation=True, title="CPT with friction compensation, load"),
    6: dict(trajectory="circle", load="none", friction_compensation=True,
            title="Circle trajectory with friction compensation, no load"),
    7: dict(trajectory="circle", load="max", friction_compensation=True,
            title="Circle trajectory with friction compensation, load"),
}

#: Epsilons per trajectory (table 1 on the CPT; section 10 raised ZC and LG+ on the circle).
CONTROLLER_PARAMS = {
    "cpt": {"sp1": {}, "sp2": {}, "zc": {"epsilon": 25.0}, "lgplus": {"eps_M": 1.5, "eps_C": 1.0},
            "lg": {"eps_M": 1.5, "eps_C": 1.0}},
    "circle": {"sp1": {}, "sp2": {}, "zc": {"epsilon": 45.0}, "lgplus": {"eps_M": 20.0, "eps_C": 2.5},
               "lg": {"eps_M": 20.0, "eps_C": 2.5}},
}

#: Circle: 7 s, error criteria over the last 6 s (section 10).
CIRCLE_SKIP = 1.0

#: JS tables 2-7 as printed, columns METRIC_KEYS (rad, rad, rad, rad, m, m). Table 4's ZC row
#: prints |error_2| = 0.113 with maxerr_2 = 0.0028, which cannot both hold for the same log
#: length as the other rows (likely a typo for 0.0113); we reproduce it as printed.
PUBLISHED = {
    2: {"sp1": (0.00624, 0.0014, 0.0644, 0.0097, 0.0216, 0.00339),
        "sp2": (0.00646, 0.0014, 0.0691, 0.0099, 0.0231, 0.00342),
        "zc": (0.0265, 0.0052, 0.0672, 0.0098, 0.0299, 0.00471),
        "lgplus": (0.00722, 0.0016, 0.0594, 0.0099, 0.0207, 0.00332)},
    3: {"sp1": (0.0126, 0.0030, 0.0636, 0.0108, 0.0235, 0.00375),
        "sp2": (0.0129, 0.0032, 0.0666, 0.0108, 0.0246, 0.00391),
        "zc": (0.0494, 0.0121, 0.0934, 0.0166, 0.0503, 0.0113),
        "lgplus": (0.0143, 0.0036, 0.0600, 0.0108, 0.0231, 0.00383)},
    4: {"sp1": (0.00442, 0.0009, 0.0224, 0.0047, 0.00746, 0.00135),
        "sp2": (0.00472, 0.0010, 0.0223, 0.0052, 0.00737, 0.00144),
        "zc": (0.0240, 0.0042, 0.113, 0.0028, 0.0156, 0.00300),
        "lgplus": (0.00478, 0.0008, 0.0251, 0.0053, 0.00933, 0.00195)},
    5: {"sp1": (0.0110, 0.0030, 0.0129, 0.0026, 0.00774, 0.00161),
        "sp2": (0.0114, 0.0032, 0.0130, 0.0026, 0.00754, 0.00165),
        "zc": (0.0459, 0.0103, 0.0568, 0.0101, 0.0405, 0.00839),
        "lgplus": (0.0130, 0.0034, 0.0139, 0.0028, 0.0099, 0.00183)},
    6: {"sp1": (0.00422, 0.0007, 0.0349, 0.0041, 0.0104, 0.00119),
        "sp2": (0.00424, 0.0005, 0.0331, 0.0037, 0.0100, 0.00113),
        "zc": (0.0681, 0.009, 0.0602, 0.0109, 0.0375, 0.00527),
        "lgplus": (0.00755, 0.0012, 0.0453, 0.0041, 0.0151, 0.00146)},
    7: {"sp1": (0.0106, 0.0011, 0.0352, 0.0047, 0.0114, 0.00161),
        "sp2": (0.0115, 0.0012, 0.0381, 0.0052, 0.0124, 0.00181),
        "zc": (0.0741, 0.0072, 0.0766, 0.0090, 0.0398, 0.00383),
        "lgplus": (0.0170, 0.002, 0.0426, 0.005, 0.0163, 0.00182)},
}

#: Paper figures that show a table's runs (maximum load, friction compensation).
FIGURES = {5: {"sp1": 4, "sp2": 5, "zc": 6, "lgplus": 7}, 7: {"sp1": 8, "sp2": 9, "zc": 10, "lgplus": 11}}


def published_row(table: int, controller: str) -> dict | None:
    vals = PUBLISHED.get(table, {}).get(controller)
    return None if vals is None else dict(zip(METRIC_KEYS, vals))


def _check_table(table) -> int:
    try:
        table = int(table)
    except (TypeError, ValueError):
        raise RobustDrakeError(f"unknown table {table!r}; the comparison has tables 2-7") from None
    if table not in TABLES:
        raise RobustDrakeError(f"unknown table {table}; the comparison has tables 2-7 (JS sections 9-10)")
    return table


def run_spec(table: int, controller: str, *, duration: float | None = None, rate: float = 2500.0,
             observer: str = "averaging", observer_params: dict | None = None, logs: bool = False,
             controller_params: dict | None = None, model: str = "rigid",
             viscous_compensation: bool = False) -> dict:
    """The spec (a plain, picklable dict) of one run behind ``table``.

    ``model``: ``"rigid"`` (the foundation's arm) or ``"flexible"`` (two-mass drives, motor-side
    encoders and link-2 bending, :func:`robust_drake.systems.flexibility.d2r2_flexibility`).

    ``duration`` shortens the run (tests, notebooks); on the circle the criteria skip
    ``min(1 s, duration / 7)`` so a shortened circle still drops the initial transient.

    ``viscous_compensation``: add ``F_v_hat v`` (F_v_hat = the plant's viscous coefficients) to the
    fixed Coulomb compensation of eqs. 89-90 (section 7.1); only for tables with compensation.
    """
    table = _check_table(table)
    _check_model(model)
    t = TABLES[table]
    traj = t["trajectory"]
    params = dict(CONTROLLER_PARAMS[traj].get(controller, {}))
    params.update(controller_params or {})
    skip = 0.0
    if traj == "circle":
        skip = CIRCLE_SKIP if duration is None else min(CIRCLE_SKIP, duration / 7.0)
    if viscous_compensation and not t["friction_compensation"]:
        raise RobustDrakeError(f"viscous compensation adds to the fixed compensation of eqs. 89-90, which table "
                               f"{table} does not use (tables 4-7 do)")
    return dict(table=table, controller=controller, load=t["load"], viscous_compensation=bool(viscous_compensation),
                friction_compensation=t["friction_compensation"], trajectory=traj,
                controller_params=params, metrics_skip=skip, duration=duration, rate=float(rate),
                observer=observer, observer_params=dict(observer_params or {}), logs=logs, model=model)


MODELS = ("rigid", "flexible")


def _check_model(model) -> str:
    if model not in MODELS:
        raise RobustDrakeError(f"unknown arm model {model!r}; known: {', '.join(MODELS)}")
    return model


def table_runs(table: int, controllers=CONTROLLERS, **kw) -> list[dict]:
    return [run_spec(table, c, **kw) for c in controllers]


def config_for(spec: dict):
    from robust_drake.diagram import ClosedLoopConfig

    return ClosedLoopConfig(
        robot="d2r2", load=spec["load"], controller=spec["controller"],
        controller_params=dict(spec["controller_params"]), trajectory=spec["trajectory"],
        rate=spec["rate"], observer=spec["observer"], observer_params=dict(spec["observer_params"]),
        friction_compensation=spec["friction_compensation"], duration=spec["duration"],
        metrics_skip=spec["metrics_skip"], flexibility=_flexibility(spec),
        compensation_params=_compensation_params(spec))


def _compensation_params(spec: dict) -> dict:
    if not spec.get("viscous_compensation"):
        return {}
    from robust_drake.systems.friction import D2R2_K_HAT, D2R2_VISCOUS

    return {"k_hat": list(D2R2_K_HAT), "viscous_hat": list(D2R2_VISCOUS)}


def _flexibility(spec: dict):
    if _check_model(spec.get("model", "rigid")) == "rigid":
        return None
    from robust_drake.systems.flexibility import d2r2_flexibility

    return d2r2_flexibility(spec["load"])


def run_one(spec: dict) -> dict:
    """Simulate one run; returns its row (and decimated logs when ``spec['logs']``)."""
    from robust_drake.diagram import simulate

    res = simulate(config_for(spec))
    row = {k: spec[k] for k in ("table", "controller", "load", "friction_compensation", "trajectory", "rate", "observer")}
    row["model"] = spec.get("model", "rigid")
    row["metrics_skip"] = float(spec.get("metrics_skip") or 0.0)  # s at the start the metrics leave out
    row["viscous_compensation"] = bool(spec.get("viscous_compensation", False))
    row.update({k: float(res.metrics[k]) for k in METRIC_KEYS})
    row.update(diverged=bool(res.diverged), divergence_reason=res.divergence_reason,
               wall_seconds=float(res.wall_seconds),
               sim_seconds=float(res.sim_seconds),
               tau_tv_per_s=list(res.torque_stats.get("tau_tv_per_s", [])),
               tau_peak=list(res.torque_stats.get("tau_peak", [])))
    if res.v_hat is not None and len(res.t) > 2:
        # quantisation noise reaching the loop: sample-to-sample jitter of the estimate's error
        row["v_noise"] = np.std(np.diff(res.v_hat - res.v, axis=0), axis=0).tolist()
    if spec.get("logs"):
        step = max(1, int(round(spec["rate"] / 500.0)))  # keep ~500 Hz for plots
        row["logs"] = {"t": res.t[::step].tolist(), "e": (res.q - res.q_d)[::step].tolist(),
                       "tau": res.tau[::step].tolist(), "q": res.q[::step].tolist(),
                       "q_d": res.q_d[::step].tolist()}
    return row


def _failed_row(spec, error):
    row = {k: spec[k] for k in ("table", "controller", "load", "friction_compensation", "trajectory", "rate", "observer")}
    row["model"] = spec.get("model", "rigid")
    row.update({k: float("nan") for k in METRIC_KEYS})
    row.update(diverged=True, error=error)
    return row


def check_spec_sizes(specs: list[dict]) -> None:
    """``diagram.check_run_size`` of every distinct (trajectory, duration, rate) of ``specs``
    (the reference's own length where no duration is given): too few ticks or too many samples
    fail at once, with one message, instead of in every run."""
    from robust_drake.diagram import check_run_size
    from robust_drake.models import get_arm
    from robust_drake.trajectories import make_reference

    for traj, duration, rate in dict.fromkeys((s["trajectory"], s.get("duration"), s["rate"]) for s in specs):
        check_run_size(duration if duration is not None else make_reference(get_arm("d2r2"), traj).duration, rate)


def run_specs(specs: list[dict], workers: int | None = None, progress: bool = True, desc="runs") -> list[dict]:
    """Run specs in parallel; a failed run is reported in its row (``error``), others complete."""
    from robust_drake.parallel import run_parallel

    check_spec_sizes(specs)  # a run of too few ticks is refused before anything starts
    outcomes = run_parallel(run_one, specs, keys=[f"t{s['table']}/{s['controller']}/{s['rate']:g}/{s.get('model', 'rigid')}" for s in specs],
                            workers=workers, desc=desc, progress=progress)
    rows = []
    for spec, o in zip(specs, outcomes):
        row = o.value if o.ok else _failed_row(spec, o.error)
        row["published"] = published_row(spec["table"], spec["controller"]) if spec.get("table") in PUBLISHED else None
        rows.append(row)
    return rows


def run_table(table: int, controllers=CONTROLLERS, workers: int | None = None, progress: bool = True,
              **kw) -> list[dict]:
    """All runs behind JS table ``table`` (2-7), in parallel."""
    table = _check_table(table)
    return run_specs(table_runs(table, controllers, **kw), workers=workers, progress=progress,
                     desc=f"table {table}")


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.3g}"


def format_paper_table(table: int, rows: list[dict]) -> str:
    """The paper's layout: one line per algorithm, each cell ``simulated (published)``."""
    from robust_drake.tables import format_table

    header = ["Algorithm", "|error1|", "maxerr1", "|error2|", "maxerr2", "|error_task|", "maxerr_task"]
    body = []
    for r in rows:
        pub = r.get("published") or {}
        name = LABELS.get(r["controller"], r["controller"])
        if r.get("model", "rigid") != "rigid":
            name += f" [{r['model']}]"
        if r.get("viscous_compensation"):
            name += " +visc"
        if "error" in r:
            body.append([name, *(["FAILED"] * 6)])
            continue
        body.append([name + (" (diverged)" if r.get("diverged") else ""),
                     *[f"{_fmt(r[k])} ({_fmt(pub.get(k))})" for k in METRIC_KEYS]])
    t = TABLES[table]
    title = f"Table {table}: {t['title']}  [simulated (published)]; joint errors in rad, task space in m"
    return title + "\n" + format_table(body, header)


#: controllers drawn in one row of :func:`plot_table` (nearly identical runs: SP1 solid, SP2 dashed)
OVERLAID = ("sp1", "sp2")


def _table_groups(rows: list[dict]) -> list[list[dict]]:
    """Rows of :func:`plot_table`: SP1 and SP2 share one row, every other controller has its own."""
    pair = [r for r in rows if r["controller"] in OVERLAID]
    groups, placed = [], False
    for r in rows:
        if r["controller"] in OVERLAID:
            if not placed:
                groups.append(pair)
                placed = True
        else:
            groups.append([r])
    return groups


def _group_name(table: int, group: list[dict]) -> str:
    parts = []
    for k, r in enumerate(group):
        fig_no = FIGURES.get(table, {}).get(r["controller"])
        style = (" solid", " dashed")[k % 2] if len(group) > 1 else ""
        parts.append(LABELS.get(r["controller"], r["controller"]) + style
                     + (" (diverged)" if r.get("diverged") else "") + (f", cf. JS fig. {fig_no}" if fig_no else ""))
    return "; ".join(parts)


#: line colours per (overlaid controller, joint): SP1 in the joint colours, SP2 in darker ones, dashed, on top
_PAIR_COLORS = (("C0", "C1"), ("#08306b", "#7f2704"))
_TASK_COLORS = ("k", "C3")


def _task_error(lg, L):
    from robust_drake.kinematics import planar_forward_kinematics

    return np.linalg.norm(planar_forward_kinematics(np.asarray(lg["q"]), L)
                          - planar_forward_kinematics(np.asarray(lg["q_d"]), L), axis=1)


def _published_note(r) -> str:
    """'LG+: maxerr_task 3.41 mm (JS 3.39), |error_task| 22.1 mm (JS 21.6)' for one row."""
    pub = r.get("published") or {}
    tag = LABELS.get(r["controller"], r["controller"])
    parts = []
    for key, what in (("maxerr_task", "maxerr_task"), ("error_task", "|error_task|")):
        sim = r.get(key)
        if sim is None or not np.isfinite(sim):
            continue
        paper = pub.get(key)
        parts.append(f"{what} {1e3 * sim:.3g} mm" + (f" (JS {1e3 * paper:.3g})" if paper is not None else ""))
    return f"{tag}: " + ", ".join(parts) if parts else ""


def _plot_group(ax_row, table, group: list[dict], L) -> None:
    """One row of :func:`plot_table`: joint errors [rad] | task-space error [mm] | torques [N m]; SP1
    solid in the joint colours, SP2 dashed in darker ones drawn on top (so both show where they
    coincide); the simulated and the published task-space criteria written in the middle panel."""
    notes = []
    for k, r in enumerate(group):
        lg, ls = r["logs"], ("-", (0, (4, 2.5)))[k % 2]
        t, e, tau = np.asarray(lg["t"]), np.asarray(lg["e"]), np.asarray(lg["tau"])
        task = _task_error(lg, L)
        tag = LABELS.get(r["controller"], r["controller"])
        colors = _PAIR_COLORS[k % 2] if len(group) > 1 else ("C0", "C1")
        lw = (1.1, 1.0)[k % 2]
        for j in range(e.shape[1]):
            ax_row[0].plot(t, e[:, j], ls=ls, color=colors[j % 2], lw=lw, label=f"{tag} e{j + 1}", zorder=2 + k)
            ax_row[2].plot(t, tau[:, j], ls=ls, color=colors[j % 2], lw=lw, label=f"{tag} tau{j + 1}", zorder=2 + k)
        ax_row[1].plot(t, 1e3 * task, ls=ls, color=_TASK_COLORS[k % 2], lw=lw, label=tag, zorder=2 + k)
        notes.append(_published_note(r))
        skip = float(r.get("metrics_skip") or 0.0)
        if skip > 0 and k == 0:
            for ax in ax_row:
                ax.axvspan(t[0], t[0] + skip, color="0.92", zorder=0,
                           label=None)
    notes = [n for n in notes if n]
    from robust_drake.models import D2R2_TORQUE_LIMIT

    for sign in (1, -1):
        ax_row[2].axhline(sign * D2R2_TORQUE_LIMIT, color="k", ls="--", lw=0.8,
                          label=f"saturation +-{D2R2_TORQUE_LIMIT:g} N m" if sign > 0 else None)
    ax_row[0].set_ylabel("joint error [rad]")
    ax_row[1].set_ylabel("task-space error [mm]")
    ax_row[2].set_ylabel("torque [N m]")
    ax_row[1].set_title(_group_name(table, group) + "".join("\n" + n for n in notes), fontsize=9)
    for ax in (ax_row[0], ax_row[2]):
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=1)


def _column_limits(axes, groups, L) -> None:
    """One y-range per column over every row, set on the samples the metrics measure (after the
    skipped first second of the circle): the start-up transient does not flatten the rest."""
    from robust_drake.plotting import window_limits

    cols = {0: [], 1: [], 2: []}
    for group in groups:
        for r in group:
            lg = r["logs"]
            t = np.asarray(lg["t"])
            skip = float(r.get("metrics_skip") or 0.0)
            for c, y in ((0, np.asarray(lg["e"])), (1, 1e3 * _task_error(lg, L)), (2, np.asarray(lg["tau"]))):
                cols[c].append(window_limits(t, y, skip, pad=0.0) if y.size else (0.0, 0.0))
    for c, spans in cols.items():
        lo, hi = min(a for a, _ in spans), max(b for _, b in spans)
        if c == 1:
            lo = 0.0
        if c == 2:  # the saturation lines stay in view
            from robust_drake.models import D2R2_TORQUE_LIMIT

            lo, hi = min(lo, -D2R2_TORQUE_LIMIT), max(hi, D2R2_TORQUE_LIMIT)
        pad = 0.12 * (hi - lo if hi > lo else 1.0)
        for ax in axes[:, c]:
            ax.set_ylim(lo - (0 if c == 1 else pad), hi + 2.2 * pad if c == 1 else hi + pad)


def table_figure(table: int, rows: list[dict]):
    """The figure analog of a table as a matplotlib ``Figure``: per controller, joint errors [rad],
    task-space error [mm] and torques [N m] against t [s], in separate columns whose y-limits are
    shared by all rows (set on the samples the metrics measure: the circle's first second is
    shaded and its transient clipped), so controllers compare row to row; SP1 and SP2 (nearly
    identical) share a row, SP1 solid and SP2 dashed in darker colours on top; each row states its
    simulated task-space criteria beside the published ones (JS tables 2-7).

    Tables 5 and 7 are the runs of JS figures 4-7 and 8-11 (maximum load, compensation)."""
    rows = [r for r in rows if "logs" in r]
    if not rows:
        raise RobustDrakeError("table_figure needs rows run with logs=True")
    dur = max(float(np.asarray(r["logs"]["t"])[-1]) for r in rows)
    title = TABLES[table]["title"] if table in TABLES else str(table)
    return comparison_figure(rows, f"Table {table}: {title} (simulated D2R2, {dur:.3g} s per run; y-limits shared "
                                   "by all rows, set after the shaded interval the metrics skip)", table=table)


def plot_table(table: int, rows: list[dict], out_dir) -> pathlib.Path:
    """Write :func:`table_figure` to ``out_dir/table<N>.png``; returns the path."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"table{table}.png"
    table_figure(table, rows).savefig(path, dpi=90)
    return path


def comparison_figure(rows: list[dict], title: str, table=None):
    """The layout of :func:`plot_table` for any rows run with logs (``run_one``): SP1 and SP2 in one
    row, one row per other controller; returns the ``Figure`` (the demo's CPT figures)."""
    from robust_drake.models import get_arm
    from robust_drake.plotting import style, subplots

    L = get_arm("d2r2").link_lengths
    groups = _table_groups([r for r in rows if "logs" in r])
    with style():
        fig, axes = subplots(len(groups), 3, figsize=(16, 3.1 * len(groups) + 0.9), squeeze=False, sharex=True)
        for ax_row, group in zip(axes, groups):
            _plot_group(ax_row, table, group, L)
        _column_limits(axes, groups, L)
        for ax in axes[-1]:
            ax.set_xlabel("t [s]")
        fig.suptitle(title)
        fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------ sample-rate study
def sweep_specs(controllers=("sp1", "sp2", "zc"), rates=(250, 500, 1000, 2500, 5000), *, trajectory="cpt",
                load="none", friction_compensation=True, duration=None, observer="averaging") -> list[dict]:
    """Runs of the section 11 study: the same controllers (table 1 epsilons, same K, Lambda, the
    same n = 3 averaging filter) at each sample rate."""
    specs = []
    for c in controllers:
        for rate in rates:
            if not rate > 0:
                raise RobustDrakeError(f"sample rates must be positive (got {rate})")
            params = dict(CONTROLLER_PARAMS[trajectory].get(c, {})) if trajectory in CONTROLLER_PARAMS else {}
            skip = (CIRCLE_SKIP if duration is None else min(CIRCLE_SKIP, duration / 7.0)) if trajectory == "circle" else 0.0
            specs.append(dict(table=None, controller=c, load=load, friction_compensation=friction_compensation,
                              trajectory=trajectory, controller_params=params, metrics_skip=skip,
                              duration=duration, rate=float(rate), observer=observer, observer_params={},
                              logs=False))
    return specs


def sweep_rate(controllers=("sp1", "sp2", "zc"), rates=(250, 500, 1000, 2500, 5000), workers=None,
               progress=True, **kw) -> list[dict]:
    """Rows with ``controller``, ``rate``, the six metrics, ``chattering`` (sum over joints of the
    torque's total variation per second, N m/s) and ``diverged``."""
    rows = run_specs(sweep_specs(controllers, rates, **kw), workers=workers, progress=progress, desc="sweep-rate")
    for r in rows:
        r.pop("published", None)
        r.pop("table", None)
        tv = r.get("tau_tv_per_s") or []
        r["chattering"] = float(sum(tv)) if tv and "error" not in r else float("nan")
    return rows


def sweep_figure(rows: list[dict]):
    """Section 11 as a ``Figure``: |error_task| [m] and chattering (torque total variation per
    second [N m/s]) against the sample rate [Hz], one line per controller (paper names)."""
    from robust_drake.plotting import style, subplots

    with style():
        fig, (a1, a2) = subplots(1, 2, figsize=(10.5, 4.0))
        for c in dict.fromkeys(r["controller"] for r in rows):
            rs = sorted((r for r in rows if r["controller"] == c), key=lambda r: r["rate"])
            rate = [r["rate"] for r in rs]
            a1.semilogx(rate, [r["error_task"] for r in rs], "o-", label=LABELS.get(c, c))
            a2.loglog(rate, [r["chattering"] for r in rs], "o-", label=LABELS.get(c, c))
        rates = sorted({r["rate"] for r in rows})
        for ax in (a1, a2):
            ax.set_xticks(rates)
            ax.set_xticklabels([f"{x:g}" for x in rates])
            ax.minorticks_off()
            ax.set_xlabel("sample rate [Hz]")
        a1.set_ylabel("|error_task| [m]")
        a2.set_ylabel("torque total variation [N m/s]")
        a1.legend()
        a1.set_title("tracking (JS eq. 58)")
        a2.set_title("chattering")
        fig.tight_layout()
    return fig


def plot_sweep(rows: list[dict], path) -> pathlib.Path:
    """Write :func:`sweep_figure` to ``path`` (PNG)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_figure(rows).savefig(path, dpi=90)
    return path


# ------------------------------------------------------------------------------ friction (section 7)
#: Section 7.2 as the paper reports it (no numbers are printed for these variants).
FRICTION_PAPER = {
    "coulomb": "tables 4-5 (eqs. 89-90, k_hat = (1, 2) N m)",
    "coulomb+viscous": "not significantly better than Coulomb only (sec. 7.1)",
    "sp1_robust_friction": "not better than fixed compensation (sec. 7.2)",
    "sp2_robust_friction": "not better than fixed compensation (sec. 7.2)",
    "zc_robust_friction": "much worse than fixed compensation (sec. 7.2)",
    "lgplus_robust_friction": "much worse than fixed compensation (sec. 7.2)",
}


def friction_curve(qd_max: float = 3.0, points: int = 601) -> dict:
    """JS fig. 3: friction torque against joint velocity for both D2R2 joints (eqs. 86-88) with the
    simulated plant's parameters, beside the Coulomb-only approximation of eqs. 89-90
    (``k_hat sgn qd``) and the Coulomb + viscous one. Velocities in rad/s, torques in N m."""
    from robust_drake.systems.friction import D2R2_COULOMB, D2R2_K_HAT, D2R2_VISCOUS, coulomb_viscous_force

    qd = np.linspace(-qd_max, qd_max, points)
    Q = np.column_stack([qd, qd])
    return {"qd": qd, "plant": coulomb_viscous_force(Q, D2R2_COULOMB, D2R2_VISCOUS),
            "coulomb_hat": coulomb_viscous_force(Q, D2R2_K_HAT, (0.0, 0.0)),
            "coulomb_viscous_hat": coulomb_viscous_force(Q, D2R2_K_HAT, D2R2_VISCOUS),
            "coulomb": list(D2R2_COULOMB), "viscous": list(D2R2_VISCOUS), "k_hat": list(D2R2_K_HAT)}


def friction_figure(qd_max: float = 3.0):
    """JS fig. 3 analog as a ``Figure``: friction torque F_j [N m] against qd_j [rad/s] of the
    simulated plant, its Coulomb approximation (eqs. 89-90) and the Coulomb + viscous one."""
    from robust_drake.plotting import style, subplots

    c = friction_curve(qd_max)
    with style():
        fig, axes = subplots(1, 2, figsize=(10.5, 4.0))
        for j, ax in enumerate(axes):
            ax.plot(c["qd"], c["plant"][:, j], "-", lw=1.6, label="plant friction (eq. 86)")
            ax.plot(c["qd"], c["coulomb_hat"][:, j], ":", lw=1.6, label="Coulomb approximation (eqs. 89-90)")
            ax.plot(c["qd"], c["coulomb_viscous_hat"][:, j], "--", label="Coulomb + viscous compensation")
            ax.set(xlabel=f"qd{j + 1} [rad/s]", ylabel=f"F{j + 1} [N m]", title=f"joint {j + 1}")
        axes[0].legend(fontsize=8.5)
        fig.suptitle("Friction torque and its approximation (cf. JS fig. 3, simulated D2R2 parameters)")
        fig.tight_layout()
    return fig


def plot_friction_curve(path, qd_max: float = 3.0) -> pathlib.Path:
    """Write the JS fig. 3 analog (:func:`friction_figure`) to ``path`` (png)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    friction_figure(qd_max).savefig(path, dpi=90)
    return path


def friction_study_specs(controllers=CONTROLLERS, *, load: str = "none", duration=None, model: str = "rigid",
                         robust=True) -> list[dict]:
    """Runs of section 7 on the CPT: each controller with the fixed Coulomb compensation (eqs. 89-90),
    with Coulomb + viscous compensation, and (``robust``) with the friction inside its robust law
    (``<controller>_robust_friction``, no fixed compensation). ``variant`` names the scheme."""
    table_comp = 4 if load == "none" else 5
    table_none = 2 if load == "none" else 3
    specs = []
    for c in controllers:
        for variant, kw in (("coulomb", {}), ("coulomb+viscous", {"viscous_compensation": True})):
            s = run_spec(table_comp, c, duration=duration, model=model, **kw)
            s["variant"] = variant
            specs.append(s)
        rf = {"lgplus": "lgplus_robust_friction", "lg": "lg_robust_friction", "zc": "zc_robust_friction",
              "sp1": "sp1_robust_friction", "sp2": "sp2_robust_friction"}.get(c)
        if robust and rf:
            s = run_spec(table_none, c, duration=duration, model=model)
            s.update(controller=rf, variant="robust", controller_params={})
            specs.append(s)
    return specs


def friction_study(controllers=CONTROLLERS, *, load="none", duration=None, model="rigid", workers=None,
                   progress=False, robust=True) -> list[dict]:
    """Section 7 comparison; rows carry ``base`` (the rigid-law name), ``variant`` and ``paper``."""
    specs = friction_study_specs(controllers, load=load, duration=duration, model=model, robust=robust)
    rows = run_specs(specs, workers=workers, progress=progress, desc="friction")
    for spec, r in zip(specs, rows):
        r["variant"] = spec["variant"]
        r["base"] = spec["controller"].replace("_robust_friction", "")
        r["paper"] = FRICTION_PAPER.get(spec["controller"] if spec["variant"] == "robust" else spec["variant"])
        if spec["variant"] != "coulomb":
            r["published"] = None
    return rows
