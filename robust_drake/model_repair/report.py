"""The repair's report: ``report.json`` and ``report.md`` rendered from ONE result.

:func:`build_report` turns the pipeline's :class:`RepairResult` (``stages.py``) into the strict
JSON dictionary; :func:`render_markdown` reads only that dictionary, so the two files can never
disagree (one statement per fact: e.g. the Hausman test's significance is
``estimator.hausman.significant`` in both, the estimator actually used is ``estimator.method``).
Joints are numbered from 1 in every text (``joint 2 (joint2)``, effect labels ``spring[2]``,
the residual's signal names ``q2``, ``qd1`` as the CSV columns), with the URDF's joint names
(``joint_names``); the integer ``joint`` fields of report.json are 0-based indices into
``joint_names`` (Python's, as ``Effect.joint``; see ``conventions`` in the report).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from robust_drake.joints import joint_numbers, joint_text
from robust_drake.model_repair import residual as R
from robust_drake.model_repair.diagnostics import stuck_rows_split
from robust_drake.model_repair.stages import identified_models, reference_rms

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure


@dataclass
class RepairResult:
    """Everything the stages produced (see ``stages.py`` for the types)."""

    opts: object
    inputs: object
    baseline: object
    estimator: object
    selection: object
    guard: object
    final: object
    nominal: dict | None
    consistent: object
    replay: dict
    warnings: list
    #: ``diagnostics.setup_change_of``: the validation run against the fit run's own held-out error
    setup_change: dict | None = None


#: the rules of stages.validated_gain_guard (an effect that is not a significant gain on its joint)
GAIN_RULES = ("velocity_shape", "validated_gain")


def once(messages: list[str]) -> list[str]:
    """The warnings in order, each once; of the poor-excitation warnings (one per fit, each with its
    own condition number, ``least_squares.poor_excitation_text``) only the first, the baseline's."""
    from robust_drake.identification.least_squares import POOR_EXCITATION

    out, poor = [], False
    for m in dict.fromkeys(messages):
        if m.startswith(POOR_EXCITATION):
            if poor:
                continue
            poor = True
        out.append(m)
    return out


def _rms(r):
    return [float(x) for x in np.sqrt(np.mean(np.asarray(r) ** 2, axis=0))]


def strict(obj):
    """The report as strict JSON values: numpy -> Python, NaN/inf -> None (``report.json`` must
    load in any JSON parser; an unidentifiable parameter's infinite standard error becomes null)."""
    if isinstance(obj, dict):
        return {k: strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def verdict(res: RepairResult) -> dict:
    """``repaired`` when the final (free-fit) model differs from the baseline: at least one
    residual-selected effect, or the IV estimate, survived the never-worse rule."""
    kept = bool(res.selection.chosen) or res.estimator.iv
    named = [e["label"] for e in res.final.effects_out if e.get("source") == "parameter_shift"]
    tried = [s for s in res.selection.steps if s.accepted]
    only_gain = bool(res.guard.dropped) and all(d.get("rule") in GAIN_RULES for d in res.guard.dropped)
    sc = res.setup_change or {}
    replayed = bool((res.replay or {}).get("before") and (res.replay or {}).get("after"))
    if sc.get("flagged"):
        joints = ", ".join(_joint(None, j, res.inputs.joint_names) for j in sc["joints"])
        return {"verdict": "no_improvement",
                "verdict_reason": f"the validation run does not match the fit run's arm/setup (joint(s) {joints}: "
                                  "validation error beyond the fit run's own held-out error, see setup_change); no "
                                  "effect is claimed on the strength of that validation"
                                  + (f" ({len(res.selection.chosen)} effect(s) fitted, unconfirmed)" if res.selection.chosen else "")}
    if kept:
        why = (f"{len(res.selection.chosen)} effect(s) kept ({res.estimator.method}); no joint validates worse "
               f"than the baseline by more than {res.guard.tolerance:.0%} beyond its spread (paired block test, "
               f"{res.guard.level:.0%}, Holm over joints)"
               + (" and neither does the replay" if replayed else " (torque validation only: no replay ran)"))
        up = [(j, t) for j, t in enumerate(res.final.validate_change) if t.low > 0]
        if up:  # worse at the level on its own, inside the margin / after Holm: said, not hidden
            why += "; but " + ", ".join(
                f"{_joint(None, j, res.inputs.joint_names)} validates {100 * t.estimate:+.1f} % "
                f"[{100 * t.low:+.1f}, {100 * t.high:+.1f}] worse" for j, t in up) + " (within that margin)"
    elif not tried and not res.guard.dropped:
        why = "nothing kept: no candidate passed the selection"
    elif only_gain:
        why = ("nothing kept: what the selection found (" + ", ".join(d["label"] for d in res.guard.dropped)
               + ") is not a significant gain on its joint's validation rows (a friction shape: away from its "
               "velocity reversals; see rejected_effects)")
    else:
        what = " and ".join(w for w, k in (("every effect tried", tried),
                                          ("the switch to instrumental variables",
                                           any(d["kind"] == "estimator" for d in res.guard.dropped))) if k)
        why = (f"nothing kept: {what or 'everything tried'} made a joint's validation"
               + (" or the replay" if replayed else "") + " worse than the least-squares baseline (see rejected_effects)"
               + ("" if replayed else "; no replay ran"))
    shapes = [d["label"] for d in res.guard.dropped if d.get("rule") in GAIN_RULES]
    if shapes and not (only_gain and not kept):
        why += (f"; not kept: {', '.join(shapes)} (not a significant gain on its joint's validation rows, "
                "see rejected_effects)")
    if named:
        why += f"; named from the URDF comparison (not part of the fitted model): {', '.join(named)}"
    return {"verdict": "repaired" if kept else "no_improvement", "verdict_reason": why}


#: report.json's statement of how joints are numbered (README, "Joint numbering")
JOINT_CONVENTION = ("text, labels and signal names number joints from 1 in URDF order (joint 2 = joint_names[1], "
                    "spring[2], q2); integer fields named joint/joints are 0-based indices into joint_names")


def build_report(res: RepairResult) -> dict:
    """The strict ``report.json`` dictionary (contract keys in ``repair.py``'s docstring)."""
    inp, base, fin, sel = res.inputs, res.baseline, res.final, res.selection
    ident = base.fit.as_dict()
    unident = list(base.fit.unidentifiable) + [
        f"joint {j + 1} ({inp.joint_names[j]}, within {inp.data.position_counts[j]:.0f} encoder counts)" for j in inp.frozen]
    final_ana = R.analyse(inp.fit, fin.fit.residual, validation=(inp.val, fin.val_residual))
    base_model, model = _models(res)
    report = {
        "robot": str(res.opts.robot),
        "joint_names": list(inp.joint_names),
        "samples": int(inp.fit.N),
        "samples_validate": int(inp.val.N),
        "torque": res.opts.torque,
        # rms_fit over the rows the fit uses (stuck rows left out: ColumnCache.rms), as predict scores it
        "baseline": {"rms_fit": inp.cf.rms(base.fit.residual).tolist(), "rms_validate": base.rms_validate,
                     **stuck_rows_split(inp.val, base.val_residual),
                     "parameters": ident["parameters"], "standard_errors": ident["standard_errors"]},
        "effects": fin.effects_out,
        "rejected_effects": [{**d, "kept": False} for d in res.guard.dropped],
        "final": {"rms_fit": inp.cf.rms(fin.fit.residual).tolist(), "rms_validate": _rms(fin.val_residual),
                  **stuck_rows_split(inp.val, fin.val_residual),
                  "parameters": fin.fit.as_dict()["parameters"],
                  "standard_errors": fin.fit.as_dict()["standard_errors"],
                  "validate_change": [t.as_dict() for t in fin.validate_change]},
        **verdict(res),
        "never_worse": _never_worse(res),
        "unexplained_structure": bool(final_ana["unexplained_structure"] or (res.setup_change or {}).get("flagged")),
        "setup_change": res.setup_change,
        "nominal": res.nominal,
        "estimator": res.estimator.report,
        "unexplained_where": final_ana["where"] + _setup_where(res.setup_change),
        "replay": res.replay,
        "consistent": res.consistent.report,
        "identifiability": {"condition_number": base.fit.cond, "rank": base.fit.rank,
                            "unidentifiable": unident, "unidentifiable_joints": inp.frozen},
        "units": inp.units,
        "conventions": {"joints": JOINT_CONVENTION},
        "selection": {"steps": [s.as_dict() for s in sel.steps], "min_gain": res.opts.min_gain,
                      "candidates": len(sel.candidates), "last_ranking": sel.ranking[:12], "rows": sel.rows,
                      "rule": "blocked 4-fold held-out error with a gap (filter settling + residual correlation "
                              "time) on the search rows ranks the candidates (winner's gain >= min_gain / 2); the "
                              "winner is accepted if it lowers the error on a held-out tail of every segment "
                              "the search never saw by >= min_gain; every "
                              "kind's parameters physically admissible"},
        "residual": {"baseline": base.analysis, "final": final_ana,
                     "final_validate": R.analyse(inp.val, fin.val_residual)},
        "data": {"fit": inp.fit.summary(), "validate": inp.val.summary(),
                 "validation_source": "files" if inp.validate_paths else "tail of fit files"},
        "warnings": list(res.warnings),
        "notes": inp.notes,
        "model": model.to_json(),
        "baseline_model": base_model.to_json(),
    }
    _finish(report, res)
    return strict(report)


def _finish(report: dict, res: RepairResult) -> None:
    """Effects annotated (:func:`annotate_effects`) and ``claimed`` (kept AND validated on a run
    that matches the fit run's setup); the estimator says when the Hausman test alone decided."""
    annotate_effects(report["effects"], res.inputs.fit.dt)
    flagged = bool((res.setup_change or {}).get("flagged"))
    for e in report["effects"]:
        e["claimed"] = not flagged
        if flagged:
            e["reason"] += "; not claimed: the validation run does not match the fit run's setup (setup_change)"
    est = report.get("estimator") or {}
    if (est.get("hausman") or {}).get("significant") and "replay_fit" not in est:
        est["decided_by"] = ("the Hausman test alone: the replay check of the fit data's motion did not run "
                             "(needs the replay and the physically consistent fit on)")


def grid_edge(kind: str, parameters: dict) -> list[str]:
    """The shape parameters of an effect of ``kind`` chosen at the smallest or largest value of
    its kind's candidate grid (``effects.EFFECTS[kind].shape_grid``, grids of two or more values):
    the data may want a value beyond the grid, so the value is a bound, not a physical estimate.
    Returns lines such as ``"transition_velocity = 1 at the edge of its grid [0.1, 1]"``."""
    from robust_drake.effects import EFFECTS

    cls = EFFECTS.get(kind)
    out = []
    for name in sorted({k for g in getattr(cls, "shape_grid", None) or [] for k in g}):
        vals = sorted({float(g[name]) for g in cls.shape_grid if name in g})
        v = parameters.get(name)
        if len(vals) >= 2 and isinstance(v, (int, float)) and (np.isclose(v, vals[0]) or np.isclose(v, vals[-1])):
            out.append(f"{name} = {v:g} at the edge of its grid [{vals[0]:g}, {vals[-1]:g}]")
    return out


def annotate_effects(rows: list[dict], dt: float) -> None:
    """Per kept effect: ``grid_edge`` (:func:`grid_edge`; the plausibility text then says so
    first), and for a time delay ``delay_samples`` = delay / dt (the fit data's mean sample
    period [s]) with its resolution: the delay is a continuous coefficient of the first-order
    expansion tau(t - d) ~ tau - d dtau/dt, not a grid value, valid for d of about a sample period
    or less."""
    for row in rows:
        edge = grid_edge(row["kind"], row.get("parameters") or {})
        row["grid_edge"] = edge
        if edge:
            row["plausibility"] = ("AT THE EDGE OF ITS GRID (" + "; ".join(edge) + "): a bound of the search, not a "
                                   "physical estimate; " + row.get("plausibility", ""))
        d = (row.get("parameters") or {}).get("delay")
        if row["kind"] == "time_delay" and isinstance(d, (int, float)):
            row["delay_samples"] = float(d / dt)
            row["plausibility"] = (row.get("plausibility", "") + f"; {d * 1e3:.3g} ms = {d / dt:.2g} sample periods "
                                   f"(mean stamp spacing {dt * 1e3:.3g} ms), estimated as a continuous coefficient "
                                   "(first-order expansion, no delay grid)")


def _setup_where(sc: dict | None) -> list[dict]:
    """The ``unexplained_where`` rows of a flagged setup change (one per joint)."""
    if not (sc and sc.get("flagged")):
        return []
    return [{"test": "setup_change", "joint": r["joint"], "ratio": r["ratio"],
             "variable": f"validation run (rms x{r['ratio']:.3g} [{r['ratio_low']:.3g}, {r['ratio_high']:.3g}] the fit "
                         "run's held-out error)", "eta2": float(1.0 - 1.0 / max(r["ratio"], 1.0) ** 2)}
            for r in sc["tests"] if r["worse"]]
def _never_worse(res: RepairResult) -> dict:
    """``never_worse``: the rule, what it tried, and the per-joint tests (``PairedTest.as_dict``) of
    the kept model's validation torque (``tests``) and replay (``replay_tests``) against the baseline."""
    g, blocks = res.guard, res.baseline.blocks
    return {"tolerance": g.tolerance, "margin": g.tolerance, "level": g.level, "attempts": g.attempts,
            "rule": "the model (its effects and the IV switch) is kept only if no joint's validation RMS torque error "
                    "is above the least-squares baseline's by more than the margin (tolerance, relative) beyond its "
                    "sampling spread, and no joint's replay RMS position error on the validation data is above the "
                    "baseline's replay (computed once) so: paired block test of the per-row squared errors at the "
                    "level (decisions.py; validation blocks of block_samples rows, replay windows as blocks), Holm "
                    "over joints",
            "reference_rms_validate": list(_reference(res)),
            "blocks": None if blocks is None else blocks.as_dict(),
            "tests": [t.as_dict() for t in g.tests], "replay_tests": [t.as_dict() for t in g.replay_tests],
            "replay_attempts": g.replay_attempts}


def _reference(res: RepairResult):
    return [float(x) for x in reference_rms(res.baseline, res.estimator)]


def _models(res: RepairResult):
    return identified_models(res.inputs, res.baseline, res.estimator, res.selection, res.final, res.consistent)


#: at most this many validation segments get a column in ``torque_validate.png``
MAX_SEGMENT_COLUMNS = 6


def torque_validate_figure(res: RepairResult) -> "Figure":
    """Measured, baseline and repaired joint torques [N m] on the validation data: one column
    per validation segment (file, or gap-free stretch of one), each on its own time axis t [s],
    one row per joint (numbered from 1, as in the report); y-limits shared along a row. Nothing is drawn across a file boundary.
    Long series are drawn as their min/max envelope (``plotting.envelope``: every spike kept)."""
    from robust_drake.plotting import style

    with style():
        return _torque_validate_figure(res)


def _torque_validate_figure(res: RepairResult) -> "Figure":
    from robust_drake.plotting import envelope, subplots

    inp, base, fin = res.inputs, res.baseline, res.final
    val = inp.val
    segs = list(dict.fromkeys(int(s) for s in val.segment))
    shown = segs[:MAX_SEGMENT_COLUMNS]
    fig, axes = subplots(val.n, len(shown), figsize=(min(16, 3.5 + 4.2 * len(shown)), 2.8 * val.n + 0.9),
                         squeeze=False, sharey="row")
    pb, pf = val.tau - base.val_residual, val.tau - fin.val_residual
    for c, s in enumerate(shown):
        m = val.segment == s
        src = val.conditioning[s].get("source") if s < len(val.conditioning) else None
        axes[0, c].set_title(os.path.basename(str(src)) if src else f"segment {s + 1}", fontsize=9)
        for j in range(val.n):
            ax = axes[j, c]
            ax.plot(*envelope(val.t[m], val.tau[m, j]), "k", lw=1.2, label="measured")
            ax.plot(*envelope(val.t[m], pb[m, j]), color="tab:red", lw=0.9, label="baseline model")
            ax.plot(*envelope(val.t[m], pf[m, j]), color="tab:blue", lw=0.9, label="repaired model")
            ax.grid(alpha=0.3)
            if c == 0:
                ax.set_ylabel(f"tau{j + 1}, joint {j + 1} ({inp.joint_names[j]}) [N m]")
        axes[-1, c].set_xlabel("t [s] (time of this file)")
    axes[0, -1].legend(loc="upper left", bbox_to_anchor=(1.02, 1.0))
    more = f"; first {len(shown)} of {len(segs)} segments shown" if len(segs) > len(shown) else ""
    fig.suptitle(f"validation torques, one column per validation file{more}", fontsize=10)
    fig.tight_layout()
    return fig


def write_plots(folder, res: RepairResult) -> list[str]:
    """Residual and torque plots of the validation data into ``folder``; returns the file names."""
    inp, base, fin = res.inputs, res.baseline, res.final
    fit, val = inp.fit, inp.val
    paths = [
        R.plot_residuals(fit, base.fit.residual, os.path.join(folder, "residual_fit.png"),
                         "fit data: torque residual of the baseline (red) and of the repaired model (blue)",
                         other=fin.fit.residual),
        R.plot_residuals(val, base.val_residual, os.path.join(folder, "residual_validate.png"),
                         "validation data: torque residual of the baseline (red) and of the repaired model (blue)", other=fin.val_residual),
    ]
    fig = torque_validate_figure(res)
    p = os.path.join(folder, "torque_validate.png")
    fig.savefig(p, dpi=80)
    paths.append(p)
    return [os.path.basename(x) for x in paths]


# ------------------------------------------------------------------------------------ markdown
def _num(x, spec: str) -> str:
    """``format(x, spec)``, or "n/a" for a value the strict report holds as null (NaN/inf)."""
    return "n/a" if x is None else format(x, spec)


def _nums(xs, spec: str = ".4f") -> str:
    return ", ".join(_num(x, spec) for x in xs)


def _names(rep: dict) -> list[str]:
    n = len(rep["baseline"]["rms_fit"])
    names = rep.get("joint_names") or []
    return names if len(names) == n else [f"joint{i + 1}" for i in range(n)]


def _joint(rep: dict | None, j, names=None) -> str:
    """``"joint 2 (name)"`` for the 0-based index 1 of a report field (joints numbered from 1)."""
    return joint_text(j, _names(rep) if names is None else names)




def signal(name: str) -> str:
    """A residual variable's name as the report shows it: its CSV name (``q2``: joint 2), as given."""
    return str(name)


def _md_header(rep: dict) -> list[str]:
    d = rep["data"]["fit"]
    return [f"# Repair report: {rep['robot']}", "",
            f"**Verdict: {rep.get('verdict', 'n/a')}** ({rep.get('verdict_reason', '')}).", "",
            f"Joints (numbered from 1 as the CSV columns q1..qn, URDF names): "
            + ", ".join(f"{j + 1} = `{nm}`" for j, nm in enumerate(_names(rep))) + ".", "",
            f"Fit samples: {rep['samples']} ({len(d['sources'])} file{'s' if len(d['sources']) != 1 else ''}); validation samples: "
            f"{rep['samples_validate']} ({_validation_source(rep)}). Torque column: `{rep['torque']}`.",
            f"Filter: {d['filter']['method']}, cut-off {d['filter']['cutoff_hz']} Hz, "
            f"{d['filter']['trim_samples']} samples trimmed at each file end.", ""]


def _validation_source(rep: dict) -> str:
    """"from 2 validation files" or "held-out tail of the fit files"."""
    if rep["data"]["validation_source"] != "files":
        return "held-out tail of the fit files"
    k = len((rep["data"].get("validate") or {}).get("sources") or [])
    return f"from {k} validation file{'s' if k != 1 else ''}" if k else "from the validation files"


def _md_rows(rep: dict) -> list[str]:
    """One line per joint: the repaired model's validation RMS on moving and on still rows."""
    f = rep["final"]
    if "stuck_share" not in f:
        return []
    L = ["", "Validation rows by motion (repaired model; still = |qd| within the stiction band or in a stuck run "
         "widened by the filter's settling, rows a fit leaves out):", ""]
    for j, (m, st, sh) in enumerate(zip(f["rms_validate_moving"], f["rms_validate_stuck"], f["stuck_share"])):
        L.append(f"- {_joint(rep, j)}: moving {_num(m, '.4f')} N m, still {_num(st, '.4f')} N m "
                 f"({_num(sh, '.0%')} of the rows still)")
    return L


def _md_setup(rep: dict) -> list[str]:
    sc = rep.get("setup_change")
    if not sc:
        return []
    explained = sc.get("explained_by_effects")
    if sc["flagged"]:
        head = ("**Flagged**: the validation run does not match the fit run's arm or setup on joint(s) "
                + ", ".join(_joint(rep, j) for j in sc["joints"]) + "; no effect is claimed on the strength of that validation.")
    elif explained:
        head = ("Not flagged: the baseline's validation error is beyond the fit run's own held-out error on joint(s) "
                + ", ".join(_joint(rep, j) for j in sc["baseline_joints"]) + ", but with the kept effects in both "
                "(second table) it is within it: an effect the baseline lacks, not a changed setup.")
    else:
        head = "Not flagged: the validation error is within the fit run's own held-out error and its spread."
    L = ["", "## Fit run vs validation run (setup change)", "", head, "", f"Rule: {sc['rule']}."]
    L += _md_setup_table(rep, sc["tests"], "baseline", "beyond" if explained else "flagged")
    again = explained or sc.get("with_effects")
    if again:
        L += _md_setup_table(rep, again["tests"], "with the kept effects", "flagged")
    return L


def _md_setup_table(rep: dict, tests: list, model: str, mark: str) -> list[str]:
    L = ["", f"| joint ({model}) | held-out RMS (fit run) | validation RMS | ratio [interval] | p |", "|---|---|---|---|---|"]
    for r in tests:
        L.append(f"| {_joint(rep, r['joint'])} | {_num(r['rms_ref'], '.4f')} | {_num(r['rms_new'], '.4f')} | "
                 f"{_num(r['ratio'], '.3g')} [{_num(r['ratio_low'], '.3g')}, {_num(r['ratio_high'], '.3g')}] | "
                 f"{_num(r['p_worse'], '.2g')}{f' **{mark}**' if r['worse'] else ''} |")
    return L


def change_text(t: dict | None) -> str:
    """``-27.0 % [-31.2, -22.5] (95 %)`` from a ``PairedTest.as_dict()`` (report.json; an infinite
    interval end is null there: "n/a")."""
    if not t or t.get("estimate") is None:
        return "n/a"
    end = lambda x: "n/a" if x is None else f"{100 * x:+.1f}"  # noqa: E731
    flag = " worse" if t.get("worse") else " better" if t.get("better") else ""
    return (f"{100 * t['estimate']:+.1f} % [{end(t.get('low'))}, {end(t.get('high'))}] ({100 * t['level']:.0f} %)"
            f"{flag}")


def _md_changes(rep: dict, tests: list, what: str) -> list[str]:
    """One line per joint: the change with its interval (``change_text``)."""
    if not tests:
        return []
    t0 = tests[0]
    return ["", f"{what} (relative RMS change against the baseline, paired block test over {t0['blocks']} blocks of "
            f"{t0['block']} samples; interval at the stated level; 'worse'/'better' after Holm over joints):", ""] + [
        f"- {_joint(rep, j)}: {change_text(t)}" for j, t in enumerate(tests)]


def _md_errors(rep: dict) -> list[str]:
    names = _names(rep)
    n = len(names)
    row = lambda label, a, b: f"| {label} | " + " | ".join(a) + " | " + " | ".join(b) + " |"  # noqa: E731
    L = ["## Error before and after (RMS torque residual per joint, N m)", "",
         "| model | " + " | ".join(f"fit {j + 1} {nm}" for j, nm in enumerate(names)) + " | "
         + " | ".join(f"validate {j + 1} {nm}" for j, nm in enumerate(names)) + " |", "|---|" + "---|" * (2 * n)]
    L.append(row("baseline (rigid body + Coulomb + viscous)", [_num(x, ".4f") for x in rep["baseline"]["rms_fit"]],
                 [_num(x, ".4f") for x in rep["baseline"]["rms_validate"]]))
    for e in rep["effects"]:
        L.append(row(f"+ {e['label']}", [""] * n, [_num(x, ".4f") for x in e["rms_validate_after"]]))
    L.append(row("**repaired**", [_num(x, ".4f") for x in rep["final"]["rms_fit"]],
                 [f"**{_num(x, '.4f')}**" for x in rep["final"]["rms_validate"]]))
    if rep.get("consistent"):
        c = rep["consistent"]
        L.append(row(f"repaired, physically consistent ({c['solver']})", [_num(x, ".4f") for x in c["rms_fit"]],
                     [_num(x, ".4f") for x in c["rms_validate"]]))
        L += _md_bodies(c)
    return L + _md_changes(rep, rep["final"].get("validate_change") or [], "Validation error of the repaired model")


def _md_bodies(c: dict) -> list[str]:
    """The consistent fit's bodies (regularised toward the URDF) beside the nearest feasible point's."""
    rows, near = c.get("plausibility") or [], c.get("nearest_feasible_bodies") or {}
    if not rows:
        return []
    reg = c.get("regularisation") or {}
    how = ("log-det divergence to the URDF, misfit within its chi-square spread "
           f"({_num(reg.get('level'), '.0%')})" if reg.get("applied") else "nearest feasible point")
    L = ["", f"Physically consistent bodies ({how}); the replay uses these:", "",
         "| link | mass [kg] | URDF [kg] | nearest feasible [kg] | COM from origin [m] | extent [m] | plausible |",
         "|---|---|---|---|---|---|---|"]
    for r in rows:
        nf = near.get(r["link"], {}).get("mass")
        L.append(f"| {r['link']} | {_num(r['mass'], '.4g')} | {_num(r['mass_urdf'], '.4g')} | {_num(nf, '.4g')} | "
                 f"{_num(r['com_distance'], '.3g')} | {_num(r['extent'], '.3g')} | "
                 f"{'yes' if r['plausible'] else 'no: ' + r['warning']} |")
    for rc in c.get("rotor_candidates") or []:
        L.append(f"- rotor inertia candidate {rc['name']} (gear ratio {_num(rc['gear_ratio'], '.4g')}): "
                 f"reflected {_num(rc['reflected_inertia'], '.4g')} kg m^2")
    if c.get("replay_trust"):
        L += ["", c["replay_trust"][0].upper() + c["replay_trust"][1:] + "."]
    return L


def _md_effects(rep: dict) -> list[str]:
    L = ["", "## Effects kept", ""]
    if not rep["effects"]:
        L.append("None." + (" No candidate passed the stopping rule." if not rep.get("rejected_effects") else ""))
    for e in rep["effects"]:
        ps = ", ".join(f"{k} = {_num(v, '.4g')}" if isinstance(v, float) else f"{k} = {v}"
                       for k, v in e["parameters"].items())
        how = ("held-out error -" + _num(e["heldout_gain"], ".1%") if e.get("heldout_gain") is not None
               else "named from the base-parameter shift against the URDF")
        L.append(f"- **{e['kind']}** ({_joint(rep, e['joint'])}): {ps}; {how}; "
                 f"confidence {e['confidence']}. Why plausible: {e['plausibility']}."
                 + ("" if e.get("claimed", True) else " **Not claimed**: the validation run does not match the "
                    "fit run's setup."))
    nw = rep.get("never_worse") or {}
    if rep.get("rejected_effects"):
        L += ["", f"Tried and dropped (never-worse rule: margin {_num(nw.get('tolerance'), '.0%')}, level "
              f"{_num(nw.get('level'), '.0%')}; {nw.get('rule', '')}; and every single-joint effect that is not a "
              "significant gain on its joint's validation rows, see each reason):", ""]
        L += [f"- {d['label']} ({_joint(rep, d['joint'])}): {d['reason']}" for d in rep["rejected_effects"]]
    return L


def _md_estimator(rep: dict) -> list[str]:
    est = rep.get("estimator") or {}
    if not est.get("hausman"):
        return []
    h = est["hausman"]
    used = "instrumental variables" if est["method"] == "instrumental_variables" else "least squares"
    if h["significant"]:
        rf = est.get("replay_fit")
        verdict = "**significant**" + (
            f"; the IV model replays the fit data's motion with mean RMS q ratio {_num(rf['ratio'], '.2f')} "
            "against LS; per joint: " + "; ".join(f"{_joint(rep, j)} {change_text(t)}"
                                                 for j, t in enumerate(rf.get("tests") or []))
            + " (IV kept unless worse on a joint)" if rf else "")
    else:
        verdict = "**not significant**"
    if est.get("decided_by"):
        verdict += f" (decided by {est['decided_by']})"
    return ["", "## Errors in variables (estimator)", "",
            "The regressor is built from positions differentiated twice; what those columns carry and "
            "the torque does not cause (motion through gear backlash at reversals, vibration, "
            "differentiated encoder noise) biases least squares towards smaller parameters. Test: instrumental "
            f"variables (the same columns low-passed at {est['instrument_cutoff_hz']:g} Hz) against least squares, "
            f"Durbin-Wu-Hausman statistic {_num(h['statistic'], '.1f')} over {h['dof']} dof (1 % limit "
            f"{_num(h['limit'], '.1f')}): {verdict}. **Estimator used: {used}.**", "",
            "Baseline structure with the IV estimate (the estimator's share of the change): validate "
            + _nums(est["baseline_iv"]["rms_validate"]) + " N m. On a held-out "
            "tail of the *same* runs the IV torque error can be higher than LS's (LS is the best "
            "equation-error predictor given equally noisy columns); the never-worse rule holds the IV "
            "switch to the same per-joint torque and replay limits as an effect."]


def _md_nominal(rep: dict) -> list[str]:
    nom = rep.get("nominal")
    if not nom:
        return []
    L = ["", "## Against the URDF's parameters", "",
         "Effects whose columns lie in the span of the rigid-body regressor (a tool payload, a rotor "
         "inertia already inside a base parameter) are absorbed exactly by a free fit; they show up "
         "only as a shift of the base parameters away from the URDF's. Shift chi^2 "
         f"{_num(nom['chi2'], '.1f')} over the {nom['dof']} directions the data identify"
         + (f" ({nom['unidentified_directions']} unidentified left out)" if nom.get("unidentified_directions") else "")
         + f" (99 % limit {_num(nom['chi2_limit'], '.1f')}; URDF "
         f"trusted to {_num(nom['sigma_rel'], '.0%')} of each parameter): "
         + ("**not significant**." if not nom["significant"] else
            f"**explained by {nom['named']}**." if nom.get("named") else
            "**significant and not explained** by any in-span effect: the URDF's inertial "
            "parameters and the fitted ones disagree in a way no single payload or rotor inertia explains."),
         "", "URDF parameters with fitted friction/effects: validate " + _nums(nom["rms_validate"]) + " N m.", "",
         "| in-span candidate | parameters | chi^2 after | decision |", "|---|---|---|---|"]
    for c in nom["span_candidates"]:
        ps = ", ".join(f"{k} = {_num(v, '.4g')}" for k, v in c["parameters"].items())
        L.append(f"| {c['label']} | {ps} | {_num(c['chi2_after'], '.1f')} | {c['reason']} |")
    return L


def _md_selection(rep: dict) -> list[str]:
    L = ["", "## Selection steps", "",
         "| step | best candidate | held-out score before -> after | confirmation block before -> after | decision |",
         "|---|---|---|---|---|"]
    for s in rep["selection"]["steps"]:
        L.append(f"| {s['step']} | {s['label']} | {_num(s['score_before'], '.4f')} -> {_num(s['score_after'], '.4f')} | "
                 f"{_num(s.get('confirm_before'), '.4f')} -> {_num(s.get('confirm_after'), '.4f')} | "
                 f"{'added' if s['accepted'] else 'stop'}: {s['reason']} |")
    sel = rep["selection"]
    return L + ["", f"Rule: {sel['rule']}; min gain {_num(sel['min_gain'], '.0%')}; {sel['candidates']} candidates. "
                "Scores are relative to the baseline's held-out error. Effect labels number joints from 1 (`spring[2]`: joint 2).", ""]


def _md_residual(rep: dict) -> list[str]:
    L = ["## Residual structure", ""]
    if rep["unexplained_structure"]:
        where = "; ".join(f"{_joint(rep, w['joint'])} vs {signal(w['variable'])} (eta^2 = {_num(w['eta2'], '.3f')})"
                          for w in rep["unexplained_where"])
        col = rep["residual"]["final"]["coloured"]
        L.append("**unexplained_structure: true.** The repaired model's residual still depends on the state "
                 f"where no library effect explains it: {where or 'none by state'}"
                 + (f"; coloured residual on joints {joint_numbers(c['joint'] for c in col)}" if col else "") + ".")
    else:
        L.append("unexplained_structure: false (no state variable explains >= "
                 f"{_num(R.ETA_MIN, '.0%')} of the residual variance at p < {R.ALPHA}).")
    L += ["", "Strongest state dependences of the final residual (eta^2 = share of residual variance explained by "
          "a binned function of the variable; signals numbered from 1 like the joints, q2 = joint 2's angle):"]
    for d in rep["residual"]["final"]["state_dependence_top"][:6]:
        L.append(f"- {_joint(rep, d['joint'])} vs {signal(d['variable'])}: eta^2 = {_num(d['eta2'], '.3f')}")
    return L


def _md_replay_and_rest(rep: dict) -> list[str]:
    L = []
    rp = rep.get("replay") or {}
    if rp.get("before") and rp.get("after"):
        L += ["", "## Replay of the measured torques through the Drake plant", "",
              f"{rp['after']['windows']} windows of {rp['after']['horizon_s']} s on the validation data, each reset "
              f"from the measured state; inertias: {rp['after']['inertias']}.", "",
              "| model | RMS q error per joint [rad] | RMS q error at window end [rad] |", "|---|---|---|",
              f"| before (baseline) | {_nums(rp['before']['rms_q'])} | {_nums(rp['before']['rms_q_end'])} |",
              f"| after (repaired + effect blocks) | {_nums(rp['after']['rms_q'])} | {_nums(rp['after']['rms_q_end'])} |"]
        L += _md_changes(rep, rp["after"].get("tests") or [], "Replay RMS q error of the repaired model (windows as "
                         "blocks)")
    ident = rep["identifiability"]
    L += ["", "## Identifiability", "",
          f"Condition number of the column-normalised baseline regressor: {_num(ident['condition_number'], '.3g')}; "
          f"unidentifiable: {', '.join(ident['unidentifiable']) or 'none'}."]
    for key, title in (("warnings", "Warnings"), ("notes", "Notes")):
        if rep.get(key):
            L += ["", f"## {title}", ""] + [f"- {w}" for w in rep[key]]
    if rep.get("plots"):
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in rep["plots"]]
    return L


def _md_truth(rep: dict) -> list[str]:
    """Simulated data (``rep["truth"]``: what the simulator was given): truth beside what was found."""
    truth = rep.get("truth")
    if not truth:
        return []
    L = ["", "## Truth (simulator input) beside what was found", "",
         "| effect | joint | parameter | truth | found | error |", "|---|---|---|---|---|---|"]
    hidden = [truth] if truth.get("kind") else []
    for h in hidden:
        f = next((e for e in rep["effects"] if e["kind"] == h["kind"] and e["joint"] == h["joint"]), None)
        for k, v in h["parameters"].items():
            got = None if f is None else f["parameters"].get(k)
            err = (f"{(got - v) / v:+.1%}" if isinstance(got, (int, float)) and isinstance(v, (int, float)) and v
                   else "")
            L.append(f"| {h['kind']} | {_joint(rep, h['joint'])} | {k} | {_num(v, '.4g')} | "
                     f"{'not found' if f is None else _num(got, '.4g')} | {err} |")
    for e in rep["effects"]:
        if not any(e["kind"] == h["kind"] and e["joint"] == h["joint"] for h in hidden):
            L.append(f"| {e['kind']} | {_joint(rep, e['joint'])} | | absent from the simulator | found | spurious |")
    fr, model = truth.get("friction"), (rep.get("model") or {}).get("friction")
    if fr and model:
        for key, name in (("coulomb", "fc"), ("viscous", "fv")):
            for j, (v, got) in enumerate(zip(fr[key], model[key])):
                err = f"{(got - v) / v:+.1%}" if v and got is not None else ""
                L.append(f"| baseline friction | {_joint(rep, j)} | {name} ({key}) | {_num(v, '.4g')} | "
                         f"{_num(got, '.4g')} | {err} |")
    if not hidden:
        L.append("| (none hidden) | | | | | |")
    return L + [""]


def render_markdown(rep: dict) -> str:
    """``report.md`` from the ``report.json`` dictionary (and nothing else)."""
    L = (_md_header(rep) + _md_truth(rep) + _md_errors(rep) + _md_rows(rep) + _md_setup(rep) + _md_effects(rep)
         + _md_estimator(rep) + _md_nominal(rep)
         + _md_selection(rep) + _md_residual(rep) + _md_replay_and_rest(rep))
    return "\n".join(L) + "\n"
