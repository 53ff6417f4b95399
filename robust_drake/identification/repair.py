"""The whole loop: identify, look at the residual, add the missing effects, report before/after.

::

    fit CSVs --(data.load)--> IdentData --(regressor + friction)--> baseline WLS
        --> residual analysis --> forward selection over effects.EFFECTS (held-out error, BIC)
        --> final WLS [+ physically consistent SDP] --> validation RMS, replay through the
            Drake plant augmented with the chosen effect blocks --> report.md / report.json / plots

``report.json`` keys (contract, issue 6)::

    {"robot", "samples", "baseline": {"rms_fit": [..], "rms_validate": [..]},
     "effects": [{"kind", "joint", "parameters", "rms_validate_after": [..]}, ...],
     "final": {"rms_fit", "rms_validate"}, "unexplained_structure": bool,
     "replay": {"before": {...}, "after": {...}}}

plus diagnostics (selection steps, identifiability, residual tests, data summary, notes).
Validation: the ``validate`` files; without them the last ``HOLDOUT_FRACTION`` of every fit file
(a contiguous tail) is held out, and the report says so.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.identification import residual as R
from robust_drake.identification.data import DEFAULT_CUTOFF_HZ, DataWarning, IdentData, frozen_joints, load
from robust_drake.identification.least_squares import load_regressor
from robust_drake.identification.selection import (
    MIN_GAIN, ColumnCache, effect_label, fit_model, forward_select, predict_tau,
)
from robust_drake.identification.least_squares import solve_wls

HOLDOUT_FRACTION = 0.25


@dataclass
class RepairOptions:
    robot: str
    torque: str = "tau_meas"
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ
    kinds: list[str] | None = None  # effect kinds to consider (default: the whole library)
    min_gain: float = MIN_GAIN
    max_effects: int = 4
    consistent: bool = True
    replay: bool = True
    replay_horizon: float = 0.2
    replay_windows: int = 20
    plots: bool = True
    weighted: bool = True
    instruments: bool = True  # errors-in-variables test; IV estimate when significant (instruments.py)
    nominal: bool = True  # compare with the URDF's parameters (nominal.py): span effects, torque_scale joint
    sigma_rel: float = 0.05  # relative trust in the URDF's base parameters for that comparison
    notes: list[str] = field(default_factory=list)


def tail_mask(data: IdentData, fraction: float = HOLDOUT_FRACTION) -> np.ndarray:
    """True on the contiguous last ``fraction`` of every file."""
    test = np.zeros(data.N, bool)
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        test[idx[int(len(idx) * (1 - fraction)):]] = True
    return test


def split_tail(data: IdentData, fraction: float = HOLDOUT_FRACTION) -> tuple[IdentData, IdentData]:
    """Hold out the contiguous last ``fraction`` of every file."""
    test = tail_mask(data, fraction)
    return data.subset(~test), data.subset(test)


def _rms(r):
    return [float(x) for x in np.sqrt(np.mean(np.asarray(r) ** 2, axis=0))]


def _friction(fit, n):
    th = dict(zip(fit.names, fit.theta))
    return [th[f"fc{i + 1}"] for i in range(n)], [th[f"fv{i + 1}"] for i in range(n)]


# physical plausibility of an identified effect, generic + hardware-aware where we know it
def plausibility(kind: str, params: dict, robot: str) -> str:
    dfki = "dfki" in str(robot)
    p = {k: v for k, v in params.items() if isinstance(v, (int, float))}
    if kind == "load_dependent_friction":
        mu = p.get("load_coefficient", np.nan)
        txt = (f"gear friction growing with transmitted torque, mu = {mu:.3g}; a planetary stage "
               "loses a few to ~20 % of the load torque")
        if dfki:
            txt += " (AK80-6: 6:1 planetary gear between rotor and joint)"
        return txt + ("" if 0 < mu < 0.5 else "; NOTE: outside the usual 0-0.5 range")
    if kind == "rotor_inertia":
        J = p.get("reflected_inertia", np.nan)
        txt = f"reflected rotor inertia {J:.3g} kg m^2"
        if dfki:
            txt += f" (AK80-6: gr^2 Ir = 36 x 6.07e-5 = {36 * 6.07e-5:.3g} kg m^2)"
        return txt
    if kind in ("stribeck", "smooth_coulomb", "asymmetric_coulomb"):
        return (f"low-velocity friction shape ({kind}); QDD motors with a single gear stage show "
                "a smooth Coulomb transition and some breakaway; backlash "
                + ("(about 0.15 deg on the AK80-6) " if dfki else "")
                + "adds a torque dip at every reversal")
    if kind == "presliding_friction":
        Fd, x0 = p.get("presliding_torque", np.nan), p.get("presliding_displacement", np.nan)
        txt = (f"presliding (Dahl) friction: {Fd:.3g} N m of the friction level builds up "
               f"over ~{x0:.3g} rad ({np.degrees(x0):.2g} deg) of motion after "
               "every reversal: compliance of gear teeth and bearings before gross sliding")
        if dfki:
            txt += " (AK80-6: 6:1 planetary stage, about 0.15 deg backlash taken up at each reversal)"
        return txt
    if kind == "torque_offset":
        return "constant torque bias: current-sensor offset of the driver or an unmodelled static load"
    if kind == "torque_scale":
        g = p.get("gain_error", np.nan)
        return (f"motor-constant error {g:+.1%}: the current-based torque estimate is off by that factor"
                + ("" if abs(g) < 0.3 else "; NOTE: larger than a motor constant usually errs"))
    if kind == "time_delay":
        d = p.get("delay", np.nan)
        return f"delay {d * 1e3:.3g} ms between recorded torque and motion (CAN bus / driver loop)" + (
            "" if 0 <= d < 0.05 else "; NOTE: unusual size or sign")
    if kind == "spring":
        return "joint-angle proportional torque: cables or a balancing spring"
    if kind == "position_dependent":
        return "position-periodic torque: cogging / torque ripple of the motor"
    if kind == "payload":
        return "extra mass at the tool"
    return kind


REPORT_FILES = ("report.md", "report.json")


def check_output_dir(out_dir, overwrite: bool) -> str:
    """Check ``out_dir`` *before* any computation; return its absolute path.

    Refused: an empty name, a path that is a file, a folder that holds an earlier report
    (``report.md`` or ``report.json``) unless ``overwrite``, and a place where no folder can be
    created (probed by creating and removing a temporary folder next to it).
    """
    import tempfile

    text = os.fspath(out_dir)
    if not str(text).strip():
        raise RobustDrakeError("--out is empty: give the folder for report.md, report.json and the plots")
    path = os.path.abspath(text)
    if os.path.exists(path) and not os.path.isdir(path):
        raise RobustDrakeError(f"--out {text} is a file, not a folder; choose a folder name")
    if os.path.isdir(path) and not overwrite:
        held = [f for f in REPORT_FILES if os.path.exists(os.path.join(path, f))]
        if held:
            raise RobustDrakeError(
                f"{text} holds an earlier repair report ({', '.join(held)}); choose another --out or "
                "pass --force to replace it")
    parent = os.path.dirname(path)
    try:
        os.makedirs(parent, exist_ok=True)
        probe = tempfile.mkdtemp(prefix=f".{os.path.basename(path)}.probe-", dir=parent)
        os.rmdir(probe)
        if os.path.isdir(path):
            fd, probe = tempfile.mkstemp(prefix=".probe-", dir=path)
            os.close(fd)
            os.remove(probe)
    except OSError as exc:
        raise RobustDrakeError(f"cannot write the report to --out {text}: "
                               f"{exc.strerror or exc} ({exc.filename or parent})") from exc
    return path


#: plot files a repair report may hold (removed with the report it belongs to)
REPORT_PLOTS = ("residual_fit.png", "residual_validate.png", "torque_validate.png", "estimator_cutoff.png")


def _report_artefacts(out: str) -> set[str]:
    """Names in ``out`` that belong to an earlier report: report.md/json and its plots."""
    names = set(REPORT_FILES) | set(REPORT_PLOTS)
    try:
        with open(os.path.join(out, "report.json")) as fh:
            names |= {os.path.basename(str(p)) for p in (json.load(fh).get("plots") or [])}
    except (OSError, ValueError, AttributeError):
        pass
    return {n for n in names if os.path.isfile(os.path.join(out, n))}


def _publish(tmp: str, out: str, keep: list[str]) -> None:
    """Move the complete report folder ``tmp`` into place at ``out``.

    * ``out`` absent: one atomic ``rename``.
    * ``out`` without an earlier report (e.g. a folder holding the input CSVs): the new files are
      moved in one by one (nothing of value is replaced).
    * ``out`` with an earlier report (``overwrite``) and nothing else but this run's inputs
      ``keep``: the inputs are copied into ``tmp``, ``out`` is renamed aside, ``tmp`` renamed to
      ``out`` and the old folder removed -- the old report's plots do not survive beside the new
      one. If the second rename fails, the old folder is put back.
    * ``out`` with an earlier report *and* other files (not ours to delete): the earlier report's
      files (report.md/json and its plots) are removed and the new ones moved in.
    In every case the report is complete in ``tmp`` before anything in ``out`` is touched.
    """
    import shutil
    import tempfile

    if not os.path.exists(out):
        os.rename(tmp, out)
        return
    old_report = _report_artefacts(out)
    keep_top = {os.path.relpath(k, out).split(os.sep)[0] for k in keep}
    foreign = set(os.listdir(out)) - old_report - keep_top
    if not old_report or foreign:
        for name in old_report:
            os.remove(os.path.join(out, name))
        for name in os.listdir(tmp):
            os.replace(os.path.join(tmp, name), os.path.join(out, name))
        os.rmdir(tmp)
        return
    for src in keep:
        dst = os.path.join(tmp, os.path.relpath(src, out))
        if not os.path.exists(dst):
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            shutil.copy2(src, dst)
    old = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.old-", dir=os.path.dirname(out))
    os.rmdir(old)
    os.rename(out, old)
    try:
        os.rename(tmp, out)
    except BaseException:
        os.rename(old, out)
        raise
    shutil.rmtree(old, ignore_errors=True)


def _inputs_inside(paths, out: str) -> list[str]:
    out_real = os.path.realpath(out)
    inside = []
    for p in paths:
        if isinstance(p, (str, os.PathLike)) and os.path.isfile(p):
            real = os.path.realpath(p)
            if os.path.commonpath([real, out_real]) == out_real:
                inside.append(real)
    return inside


def run_repair(fit_paths, options: RepairOptions, validate_paths=None, out_dir=None, progress=None,
               overwrite: bool = True) -> dict:
    """The whole loop; writes ``report.json``/``report.md``/plots into ``out_dir`` when given.

    The output folder is checked before the computation (:func:`check_output_dir`; with
    ``overwrite=False`` an earlier report there is refused, as the command line does without
    ``--force``), the report is written into a temporary folder beside it and moved into place
    only when complete (:func:`_publish`): a failure part-way leaves an earlier report untouched.
    """
    from robust_drake.identification import input_checks as IC

    from robust_drake.log import progress_callback

    log = progress_callback(progress)  # None: the "robust_drake" logger at INFO
    opts = options
    out_path = check_output_dir(out_dir, overwrite) if out_dir is not None else None
    IC.check_distinct_files(fit_paths, validate_paths)
    _check_robot_urdf(opts.robot)
    input_warnings: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        regressor = load_regressor(opts.robot)
        n = getattr(regressor, "n", None)
        if getattr(regressor, "plant", None) is not None:
            input_warnings += IC.prismatic_warnings(regressor.plant)
        data = load(fit_paths, robot=opts.robot, n_joints=n, torque=opts.torque, cutoff_hz=opts.cutoff_hz)
        notes = list(opts.notes)
        if validate_paths:
            val = load(validate_paths, robot=opts.robot, n_joints=data.n, torque=opts.torque,
                       cutoff_hz=opts.cutoff_hz)
            fit = data
        else:
            fit, val = split_tail(data)
            notes.append(f"no --validate given: the last {HOLDOUT_FRACTION:.0%} of every fit file is "
                         "held out (contiguous tail) as validation data")
        log(f"data: fit {fit.N} samples ({len(fit.sources)} files), validate {val.N} samples")
        cf, cv = ColumnCache(fit, regressor), ColumnCache(val, regressor)
        _, budget_warning = IC.sample_budget(fit, cf.base.shape[2])
        if budget_warning:
            input_warnings.append(budget_warning)
        units, unit_warnings = IC.torque_scale_check(fit, regressor)
        input_warnings += unit_warnings
        frozen = frozen_joints(data)
        for j in frozen:
            input_warnings.append(
                f"joint {j} (q{j + 1}) moves within {data.position_counts[j]:.0f} encoder count(s) in every fit "
                "file: its parameters are unidentifiable (excite that joint)")

        # ---- baseline: rigid body + Coulomb + viscous
        if opts.weighted:  # two-step WLS on the baseline fixes the per-joint weights of the selection
            Y0, names0, _ = cf.model([])
            weights = 1.0 / np.maximum(solve_wls(Y0, fit.tau, names0, warn=False).rms, 1e-12)
        else:
            weights = np.ones(fit.n)
        base_fit, _ = fit_model(cf, [], weights)
        base_val_r = val.tau - predict_tau(cv, [], base_fit.theta)
        base_ana = R.analyse(fit, base_fit.residual)
        log(f"baseline rms fit {np.round(base_fit.rms, 4)} validate {np.round(_rms(base_val_r), 4)}")

        # ---- the estimator: LS or instrumental variables (instruments.py), decided on the
        # baseline before any effect is searched for (an attenuated LS fit makes the selection
        # chase columns that only mimic the bias)
        from robust_drake.identification.effects import all_candidates

        fitter = fit_model
        estimator, cz, nf = {"method": "least_squares"}, None, 1.0
        if opts.instruments and fit.filter.cutoff_hz and fit.filter.derivatives != "given":
            from robust_drake.identification import instruments as IV

            estimator, cz, nf = _choose_estimator(opts, fit_paths, bool(validate_paths), data, fit, val, cf, cv,
                                                  regressor, [], weights, log, notes)
            if estimator["method"] == "instrumental_variables":
                fitter = lambda c, effects, w: IV.fit_model_iv(c, cz, effects, w, nf)  # noqa: E731
        icache = cz if estimator["method"] == "instrumental_variables" else None

        # ---- selection
        cands = all_candidates(fit.n, kinds=opts.kinds, robot=opts.robot)
        sel = forward_select(cf, cands, min_gain=opts.min_gain, max_effects=opts.max_effects, progress=log,
                             weights=weights, icache=icache)
        chosen = list(sel.chosen)
        steps, ranking = list(sel.steps), sel.ranking

        def refit_weights(effects):
            # second WLS step: per-joint weights from the chosen model's own residual (the
            # baseline's over-weights a joint whose residual an effect was hiding, e.g. a torque
            # scale error, and biases that effect's estimate)
            if not (opts.weighted and effects):
                return weights
            f, _ = fitter(cf, effects, weights)
            return 1.0 / np.maximum(f.rms, 1e-12)

        weights = refit_weights(chosen)
        step_label = {effect_label(e): effect_label(e) for e in chosen}
        joint_resolution = {}
        if opts.nominal:  # torque_scale: pick the joint against the URDF (nominal.resolve_torque_scale)
            from robust_drake.identification.effects import make_effect
            from robust_drake.identification.nominal import resolve_torque_scale

            p0 = len(regressor.base_names)
            for k, e in enumerate(chosen):
                if e.kind != "torque_scale" or e.joint is None:
                    continue
                fk, sl = fitter(cf, chosen, weights)
                res = resolve_torque_scale(fk.theta[:p0], fk.se[:p0], regressor.base_parameters(), e.joint,
                                           float(e.parameters(fk.theta[sl[k]])["gain_error"]), fit.n)
                if res["swapped"]:
                    new_e = make_effect("torque_scale", res["joint"])
                    step_label[effect_label(new_e)] = effect_label(e)
                    chosen[k] = new_e
                    weights = refit_weights(chosen)
                    log(f"torque_scale: the equivalent gain on joint {res['joint']} keeps the rigid-body "
                        f"parameters closer to the URDF (chi2 {res['chi2_swapped']:.1f} vs "
                        f"{res['chi2_as_fitted']:.1f}): reported there")
                joint_resolution[effect_label(chosen[k])] = res

        # ---- final model, per-effect cumulative validation
        final_fit, slices = fitter(cf, chosen, weights)
        effects_out = []
        for k, e in enumerate(chosen):
            fk, _ = fitter(cf, chosen[:k + 1], weights)
            rv = val.tau - predict_tau(cv, chosen[:k + 1], fk.theta)
            coef = final_fit.theta[slices[k]]
            se = final_fit.se[slices[k]]
            params = e.parameters(coef)
            step = next(s for s in steps if s.accepted and s.label == step_label[effect_label(e)])
            effects_out.append({
                "kind": e.kind, "joint": e.joint, "label": effect_label(e),
                "parameters": _jsonable(params),
                "coefficients": [float(c) for c in coef], "standard_errors": [float(s) for s in se],
                "rms_validate_after": _rms(rv),
                "heldout_gain": step.gain, "source": "residual",
                "confidence": "high" if step.gain >= 0.25 and not R.analyse(fit, fk.residual)["unexplained_structure"]
                else "moderate",
                "plausibility": plausibility(e.kind, params, opts.robot),
            })
            if effect_label(e) in joint_resolution:
                effects_out[-1]["joint_resolution"] = joint_resolution[effect_label(e)]
        final_val_r = val.tau - predict_tau(cv, chosen, final_fit.theta)

        # ---- against the nominal (URDF) model: effects inside the rigid-body span, torque_scale joint
        nominal = None
        if opts.nominal:
            from robust_drake.identification import nominal as NM

            nominal = NM.compare_with_nominal(cf, cv, regressor, final_fit, chosen, cands, weights,
                                              sigma_rel=opts.sigma_rel)
            named = nominal.pop("named")
            log(f"nominal (URDF) model: parameter shift chi2 {nominal['chi2']:.1f} "
                f"(99 % limit {nominal['chi2_limit']:.1f}), validate {np.round(nominal['rms_validate'], 4)}")
            if named is not None:
                e = named.pop("effect")
                effects_out.append({
                    "kind": named["kind"], "joint": named["joint"], "label": named["label"],
                    "parameters": _jsonable(named["parameters"]), "coefficients": named["coefficients"],
                    "standard_errors": [None] * len(named["coefficients"]),
                    "rms_validate_after": named["rms_validate_after"],
                    "rms_validate_before": nominal["rms_validate"],
                    "heldout_gain": None, "source": "parameter_shift",
                    "confidence": "moderate",
                    "plausibility": plausibility(e.kind, named["parameters"], opts.robot)
                    + " (inside the rigid-body span: named from the base-parameter shift against the URDF; "
                      "errors are URDF-only vs URDF + this effect)",
                })
                nominal["named"] = named["label"]
                log(f"named from the parameter shift: {named['label']} {named['parameters']}; URDF-model "
                    f"validate {np.round(nominal['rms_validate'], 4)} -> {np.round(named['rms_validate_after'], 4)}")
        final_ana = R.analyse(fit, final_fit.residual)
        val_ana = R.analyse(val, final_val_r)
        unexplained = bool(final_ana["unexplained_structure"])

        # ---- physically consistent estimate
        consistent = None
        if opts.consistent:
            try:
                def cons_for(effects, fitres):
                    use_iv = estimator["method"] == "instrumental_variables" and fitres is not base_fit
                    return _consistent_fit(regressor, opts.robot, cf, effects, weights, cz if use_iv else None)

                cons_base = cons_for([], base_fit)
                cons_final = cons_for(chosen, final_fit)
                r_cf = fit.tau - predict_tau(cf, chosen, cons_final.theta)
                r_cv = val.tau - predict_tau(cv, chosen, cons_final.theta)
                consistent = {"rms_fit": _rms(r_cf), "rms_validate": _rms(r_cv), **cons_final.as_dict()}
                log(f"consistent ({cons_final.solver}): rms validate {np.round(_rms(r_cv), 4)}")
            except RobustDrakeError as exc:
                notes.append(f"physically consistent fit not available: {exc}")
                cons_base = cons_final = None
        else:
            cons_base = cons_final = None

        # ---- replay through the Drake plant
        replay_out = {"before": None, "after": None}
        if opts.replay:
            def rp(fitres, effects, cons):
                return _replay_model(opts, cf, val, fitres, effects, cons)

            try:
                replay_out = {"before": rp(base_fit, [], cons_base), "after": rp(final_fit, chosen, cons_final)}
                log(f"replay rms q before {np.round(replay_out['before']['rms_q'], 4)} "
                    f"after {np.round(replay_out['after']['rms_q'], 4)}")
            except RobustDrakeError as exc:
                notes.append(f"replay failed: {exc}")

    warn_msgs = list(dict.fromkeys(input_warnings + sorted({str(w.message) for w in caught})))
    ident = base_fit.as_dict()
    unident = list(base_fit.unidentifiable) + [
        f"joint {j} (q{j + 1} within {data.position_counts[j]:.0f} encoder counts)" for j in frozen]
    report = {
        "robot": str(opts.robot),
        "samples": int(fit.N),
        "samples_validate": int(val.N),
        "torque": opts.torque,
        "baseline": {"rms_fit": _rms(base_fit.residual), "rms_validate": _rms(base_val_r),
                     "parameters": ident["parameters"], "standard_errors": ident["standard_errors"]},
        "effects": effects_out,
        "final": {"rms_fit": _rms(final_fit.residual), "rms_validate": _rms(final_val_r),
                  "parameters": final_fit.as_dict()["parameters"],
                  "standard_errors": final_fit.as_dict()["standard_errors"]},
        "unexplained_structure": unexplained,
        "nominal": nominal,
        "estimator": estimator,
        "unexplained_where": final_ana["where"],
        "replay": replay_out,
        "consistent": consistent,
        "identifiability": {"condition_number": base_fit.cond, "rank": base_fit.rank,
                            "unidentifiable": unident, "unidentifiable_joints": frozen},
        "units": units,
        "selection": {"steps": [s.as_dict() for s in steps], "min_gain": opts.min_gain,
                      "candidates": len(cands), "last_ranking": ranking[:12],
                      "rule": "blocked 4-fold held-out error, gain >= min_gain and BIC (N_eff) decreasing"},
        "residual": {"baseline": base_ana, "final": final_ana, "final_validate": val_ana},
        "data": {"fit": fit.summary(), "validate": val.summary(),
                 "validation_source": "files" if validate_paths else "tail of fit files"},
        "warnings": warn_msgs,
        "notes": notes,
    }
    report = _strict(report)
    if out_path is not None:
        import shutil
        import tempfile

        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out_path)}.tmp-", dir=os.path.dirname(out_path))
        try:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the report folder is not
            if opts.plots:
                report["plots"] = _plots(tmp, fit, val, base_fit, final_fit, base_val_r, final_val_r, cf, cv, chosen)
                if estimator.get("hausman") and fit_paths_are_files(fit_paths):
                    from robust_drake.identification import instruments as IV

                    fc = fit.filter.cutoff_hz
                    sweep = IV.cutoff_sweep(fit_paths, opts.robot, regressor, [0.5 * fc, 0.75 * fc, fc, 1.5 * fc],
                                            torque=opts.torque, weights=weights, n_joints=fit.n)
                    report["estimator"]["cutoff_sweep"] = sweep
                    IV.plot_cutoff_sweep(sweep, os.path.join(tmp, "estimator_cutoff.png"))
                    report["plots"].append("estimator_cutoff.png")
            write_report_files(report, tmp)
            _publish(tmp, out_path, _inputs_inside(list(fit_paths) + list(validate_paths or []), out_path))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return report


def write_report_files(report: dict, folder: str) -> None:
    """``report.json`` (strict JSON) and ``report.md`` (rendered from the same dict) in ``folder``."""
    text_json = json.dumps(report, indent=2, default=_json_default, allow_nan=False)
    text_md = render_markdown(report)
    with open(os.path.join(folder, "report.json"), "w") as fh:
        fh.write(text_json)
    with open(os.path.join(folder, "report.md"), "w") as fh:
        fh.write(text_md)


def _check_robot_urdf(robot) -> None:
    """Masses and inertias of the robot's URDF (input_checks.check_urdf_inertials), before Drake."""
    from robust_drake.identification.input_checks import check_urdf_inertials
    from robust_drake.models import resolve_urdf

    check_urdf_inertials(resolve_urdf(robot))


def _choose_estimator(opts, fit_paths, have_validation, data, fit, val, cf, cv, regressor, chosen, weights,
                      log, notes):
    """LS or IV for the model ``chosen`` (instruments.py): Hausman test, then (with the consistent
    fit and the replay on) the output-error check on the fit data. Returns (estimator report,
    instrument ColumnCache, N_eff / N)."""
    from robust_drake.identification import instruments as IV
    from robust_drake.identification.selection import n_effective

    fz = fit.filter.cutoff_hz * IV.INSTRUMENT_RATIO
    zdata = load(fit_paths, robot=opts.robot, n_joints=data.n, torque=opts.torque, cutoff_hz=fz,
                 trim_s=data.filter.trim_samples * data.dt)
    if not have_validation:
        zdata = zdata.subset(~tail_mask(zdata))
    cz = ColumnCache(zdata, regressor)
    nf = n_effective(fit) / fit.N
    ls_k, _ = fit_model(cf, chosen, weights)
    iv_k, _ = IV.fit_model_iv(cf, cz, chosen, weights, nf)
    Yk, _, _ = cf.model(chosen)
    test = IV.hausman(ls_k.theta, IV.ls_covariance(Yk, fit.tau, ls_k.theta, weights, nf), iv_k.theta, iv_k.cov)
    iv_base, _ = IV.fit_model_iv(cf, cz, [], weights, nf)
    estimator = {
        "method": "instrumental_variables" if test["significant"] else "least_squares",
        "rule": "Hausman test significant at 1 % and, with consistent fit + replay on, the IV "
                "model replays the fit data's motion at least min_gain better (mean per-joint RMS q "
                "ratio < 1 - min_gain)",
        "instrument_cutoff_hz": fz, "hausman": test,
        "baseline_iv": {"rms_fit": _rms(iv_base.residual),
                        "rms_validate": _rms(val.tau - predict_tau(cv, [], iv_base.theta))},
    }
    if test["significant"] and opts.consistent and opts.replay:
        # output error decides too: LS is the best *equation-error* predictor given the noisy
        # columns, so judge both estimates by replaying the fit data's motion
        try:
            r_ls = _replay_model(opts, cf, fit, ls_k, chosen,
                                 _consistent_fit(regressor, opts.robot, cf, chosen, weights))
            r_iv = _replay_model(opts, cf, fit, iv_k, chosen,
                                 _consistent_fit(regressor, opts.robot, cf, chosen, weights, cz))
            ratio = float(np.mean(np.asarray(r_iv["rms_q"]) / np.maximum(r_ls["rms_q"], 1e-12)))
            estimator["replay_fit"] = {"least_squares": r_ls["rms_q"], "instrumental_variables": r_iv["rms_q"],
                                       "ratio": ratio}
            estimator["replay_fit"]["required_ratio"] = 1.0 - opts.min_gain
            if not ratio < 1.0 - opts.min_gain:  # the same 5 % bar an effect has to clear
                estimator["method"] = "least_squares"
            log(f"replay of the fit data, RMS q: LS {np.round(r_ls['rms_q'], 4)}, "
                f"IV {np.round(r_iv['rms_q'], 4)} (mean ratio {ratio:.2f})")
        except RobustDrakeError as exc:
            notes.append(f"estimator replay check failed ({exc}); Hausman test alone decides")
    log(f"errors in variables: Hausman {test['statistic']:.1f} (1 % limit {test['limit']:.1f}, "
        f"{test['dof']} dof) -> {estimator['method']} (instruments low-passed at {fz:g} Hz)")
    return estimator, cz, nf


def fit_paths_are_files(paths) -> bool:
    return all(isinstance(p, (str, os.PathLike)) and os.path.isfile(p) for p in paths)


def _consistent_fit(regressor, robot, cf, effects, weights, cz=None):
    """Physically consistent estimate of ``cf.model(effects)``; with ``cz`` (instrument columns)
    in its two-stage IV form: the weighted regressor projected on the instruments' span,
    Z (Z^T Z)^-1 Z^T A (equal to IV when unconstrained)."""
    from robust_drake.identification.consistency import consistent_identification

    Y, _, _ = cf.model(effects)
    w = weights
    A = (Y * w[None, :, None]).reshape(-1, Y.shape[2])
    b = (cf.data.tau * w[None, :]).reshape(-1)
    if cz is not None:
        Z, _, _ = cz.model(effects)
        Zw = (Z * w[None, :, None]).reshape(-1, Z.shape[2])
        A = Zw @ np.linalg.lstsq(Zw, A, rcond=None)[0]
    p_base = len(regressor.base_names)
    # extras = friction + effect columns, which follow the base block
    return consistent_identification(regressor, robot, A, b, Y.shape[2] - p_base)


def _replay_model(opts, cf, data, fitres, effects, cons):
    """Replay ``data`` through the Drake plant with a fitted model (consistent inertias if given)."""
    from robust_drake.identification.replay import replay

    n = data.n
    fc, fv = _friction(fitres, n)
    theta = cons.theta if cons is not None else fitres.theta
    _, _, sl = cf.model(effects)
    eff = [(e, e.parameters(theta[s])) for e, s in zip(effects, sl)]
    if cons is not None:
        fc, fv = _friction_from(theta, fitres.names, n)
    inert = (cons.body_names, cons.pi, cons.extras) if cons is not None else None
    return replay(opts.robot, data, fc, fv, eff, inertias=inert, horizon=opts.replay_horizon,
                  max_windows=opts.replay_windows)


def _friction_from(theta, names, n):
    th = dict(zip(names, theta))
    return [th[f"fc{i + 1}"] for i in range(n)], [th[f"fv{i + 1}"] for i in range(n)]


def _jsonable(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, np.generic):
            v = v.item()
        out[k] = v
    return out


def _strict(obj):
    """The report as strict JSON values: numpy -> Python, NaN/inf -> None (``report.json`` must
    load in any JSON parser; an unidentifiable parameter's infinite standard error becomes null)."""
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _strict(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def _plots(out_dir, fit, val, base_fit, final_fit, base_val_r, final_val_r, cf, cv, chosen) -> list[str]:
    from robust_drake.plotting import subplots

    paths = [
        R.plot_residuals(fit, base_fit.residual, os.path.join(out_dir, "residual_fit.png"),
                         "fit data: residual of the baseline (red) and of the repaired model (blue)",
                         other=final_fit.residual),
        R.plot_residuals(val, base_val_r, os.path.join(out_dir, "residual_validate.png"),
                         "validation data: baseline (red) vs repaired (blue)", other=final_val_r),
    ]
    fig, axes = subplots(val.n, 1, figsize=(11, 2.6 * val.n), squeeze=False)
    pb = val.tau - base_val_r
    pf = val.tau - final_val_r
    for j in range(val.n):
        ax = axes[j, 0]
        ax.plot(val.t, val.tau[:, j], "k", lw=1, label="measured")
        ax.plot(val.t, pb[:, j], "r", lw=0.8, label="baseline")
        ax.plot(val.t, pf[:, j], "b", lw=0.8, label="repaired")
        ax.set_ylabel(f"tau{j + 1} [N m]")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s] (validation files back to back)")
    fig.tight_layout()
    p = os.path.join(out_dir, "torque_validate.png")
    fig.savefig(p, dpi=80)
    paths.append(p)
    return [os.path.basename(x) for x in paths]


def _num(x, spec: str) -> str:
    """``format(x, spec)``, or "n/a" for a value the strict report holds as null (NaN/inf)."""
    return "n/a" if x is None else format(x, spec)


def render_markdown(rep: dict) -> str:
    n = len(rep["baseline"]["rms_fit"])
    fmt = lambda xs: ", ".join(f"{_num(x, '.4f')}" for x in xs)  # noqa: E731
    L = [f"# Repair report: {rep['robot']}", ""]
    L += [f"Fit samples: {rep['samples']} ({len(rep['data']['fit']['sources'])} files); validation samples: "
          f"{rep['samples_validate']} ({rep['data']['validation_source']}). Torque column: `{rep['torque']}`.",
          f"Filter: {rep['data']['fit']['filter']['method']}, cut-off {rep['data']['fit']['filter']['cutoff_hz']} Hz, "
          f"{rep['data']['fit']['filter']['trim_samples']} samples trimmed at each file end.", ""]
    L += ["## Error before and after (RMS torque residual per joint, N m)", "",
          "| model | " + " | ".join(f"fit j{j}" for j in range(n)) + " | " + " | ".join(f"validate j{j}" for j in range(n)) + " |",
          "|---|" + "---|" * (2 * n)]
    L.append("| baseline (rigid body + Coulomb + viscous) | " + " | ".join(f"{_num(x, '.4f')}" for x in rep["baseline"]["rms_fit"])
             + " | " + " | ".join(f"{_num(x, '.4f')}" for x in rep["baseline"]["rms_validate"]) + " |")
    for e in rep["effects"]:
        L.append(f"| + {e['label']} | " + " | ".join("" for _ in range(n)) + " | "
                 + " | ".join(f"{_num(x, '.4f')}" for x in e["rms_validate_after"]) + " |")
    L.append("| **repaired** | " + " | ".join(f"{_num(x, '.4f')}" for x in rep["final"]["rms_fit"]) + " | "
             + " | ".join(f"**{_num(x, '.4f')}**" for x in rep["final"]["rms_validate"]) + " |")
    if rep.get("consistent"):
        c = rep["consistent"]
        L.append(f"| repaired, physically consistent ({c['solver']}) | " + " | ".join(f"{_num(x, '.4f')}" for x in c["rms_fit"])
                 + " | " + " | ".join(f"{_num(x, '.4f')}" for x in c["rms_validate"]) + " |")
    L += ["", "## Effects added", ""]
    if not rep["effects"]:
        L.append("None: no candidate passed the stopping rule.")
    for e in rep["effects"]:
        ps = ", ".join(f"{k} = {_num(v, '.4g')}" if isinstance(v, float) else f"{k} = {v}" for k, v in e["parameters"].items())
        L.append(f"- **{e['kind']}** (joint {e['joint']}): {ps}; {'held-out error -' + _num(e['heldout_gain'], '.1%') if e.get('heldout_gain') is not None else 'named from the base-parameter shift against the URDF'}; "
                 f"confidence {e['confidence']}. Why plausible: {e['plausibility']}.")
    est = rep.get("estimator") or {}
    if est.get("hausman"):
        h = est["hausman"]
        L += ["", "## Errors in variables (estimator)", "",
              "The regressor is built from positions differentiated twice; what those columns carry and "
              "the torque does not cause (motion through gear backlash at reversals, vibration, "
              "differentiated encoder noise) biases least squares towards smaller parameters. Test: instrumental variables "
              f"(the same columns low-passed at {est['instrument_cutoff_hz']:g} Hz) against least squares, "
              f"Durbin-Wu-Hausman statistic {_num(h['statistic'], '.1f')} over {h['dof']} dof (1 % limit "
              f"{_num(h['limit'], '.1f')}): " + ("**significant: the repaired model uses the IV estimate.**"
                                        if est["method"] == "instrumental_variables" else
                                        "not significant: least squares kept."), "",
              "Baseline structure with the IV estimate (the estimator's share of the change): validate "
              + ", ".join(f"{_num(x, '.4f')}" for x in est["baseline_iv"]["rms_validate"]) + " N m. On a held-out "
              "tail of the *same* runs the IV torque error can be higher than LS's (LS is the best "
              "equation-error predictor given equally noisy columns); the replay below judges the motion."]
    nom = rep.get("nominal")
    if nom:
        L += ["", "## Against the URDF's parameters", "",
              "Effects whose columns lie in the span of the rigid-body regressor (a tool payload, a rotor "
              "inertia already inside a base parameter) are absorbed exactly by a free fit; they show up "
              "only as a shift of the base parameters away from the URDF's. Shift chi^2 "
              f"{_num(nom['chi2'], '.1f')} over {nom['dof']} parameters (99 % limit {_num(nom['chi2_limit'], '.1f')}; URDF "
              f"trusted to {_num(nom['sigma_rel'], '.0%')} of each parameter): "
              + ("**not significant**." if not nom["significant"] else
                 f"**explained by {nom['named']}**." if nom.get("named") else
                 "**significant and not explained** by any in-span effect: the URDF's inertial "
                 "parameters and the fitted ones disagree in a way no single payload or rotor inertia explains."),
              "", f"URDF parameters with fitted friction/effects: validate "
              + ", ".join(f"{_num(x, '.4f')}" for x in nom["rms_validate"]) + " N m.", "",
              "| in-span candidate | parameters | chi^2 after | decision |", "|---|---|---|---|"]
        for c in nom["span_candidates"]:
            ps = ", ".join(f"{k} = {_num(v, '.4g')}" for k, v in c["parameters"].items())
            L.append(f"| {c['label']} | {ps} | {_num(c['chi2_after'], '.1f')} | {c['reason']} |")
    L += ["", "## Selection steps", "", "| step | best candidate | held-out score before -> after | BIC before -> after | decision |",
          "|---|---|---|---|---|"]
    for s in rep["selection"]["steps"]:
        L.append(f"| {s['step']} | {s['label']} | {_num(s['score_before'], '.4f')} -> {_num(s['score_after'], '.4f')} | "
                 f"{_num(s['bic_before'], '.1f')} -> {_num(s['bic_after'], '.1f')} | {'added' if s['accepted'] else 'stop'}: {s['reason']} |")
    L += ["", f"Rule: {rep['selection']['rule']}; min gain {_num(rep['selection']['min_gain'], '.0%')}; "
          f"{rep['selection']['candidates']} candidates. Scores are relative to the baseline's held-out error.", ""]
    L += ["## Residual structure", ""]
    if rep["unexplained_structure"]:
        where = "; ".join(f"joint {w['joint']} vs {w['variable']} (eta^2 = {_num(w['eta2'], '.3f')})" for w in rep["unexplained_where"])
        col = rep["residual"]["final"]["coloured"]
        L.append("**unexplained_structure: true.** The repaired model's residual still depends on the state "
                 f"where no library effect explains it: {where or 'none by state'}"
                 + (f"; coloured residual on joints {[c['joint'] for c in col]}" if col else "") + ".")
    else:
        L.append("unexplained_structure: false (no state variable explains >= "
                 f"{_num(R.ETA_MIN, '.0%')} of the residual variance at p < {R.ALPHA}).")
    L.append("")
    L.append("Strongest state dependences of the final residual (eta^2 = share of residual variance explained by a "
             "binned function of the variable):")
    for d in rep["residual"]["final"]["state_dependence_top"][:6]:
        L.append(f"- joint {d['joint']} vs {d['variable']}: eta^2 = {_num(d['eta2'], '.3f')}")
    rp = rep.get("replay") or {}
    if rp.get("before") and rp.get("after"):
        L += ["", "## Replay of the measured torques through the Drake plant", "",
              f"{rp['after']['windows']} windows of {rp['after']['horizon_s']} s on the validation data, each reset "
              f"from the measured state; inertias: {rp['after']['inertias']}.", "",
              "| model | RMS q error per joint [rad] | RMS q error at window end [rad] |", "|---|---|---|",
              f"| before (baseline) | {fmt(rp['before']['rms_q'])} | {fmt(rp['before']['rms_q_end'])} |",
              f"| after (repaired + effect blocks) | {fmt(rp['after']['rms_q'])} | {fmt(rp['after']['rms_q_end'])} |"]
    ident = rep["identifiability"]
    L += ["", "## Identifiability", "",
          f"Condition number of the column-normalised baseline regressor: {_num(ident['condition_number'], '.3g')}; "
          f"unidentifiable: {', '.join(ident['unidentifiable']) or 'none'}."]
    if rep.get("warnings"):
        L += ["", "## Warnings", ""] + [f"- {w}" for w in rep["warnings"]]
    if rep.get("notes"):
        L += ["", "## Notes", ""] + [f"- {w}" for w in rep["notes"]]
    if rep.get("plots"):
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in rep["plots"]]
    return "\n".join(L) + "\n"


def run_repair_demo(out_dir: str, kind: str = "stribeck", seed: int = 0, progress=None, **options) -> dict:
    """The whole loop on a built-in simulated experiment (no shared data needed).

    The "true" arm (DFKI C.1 URDF + baseline friction + one hidden ``kind`` effect from
    ``simulated.HIDDEN_CASES``, PD-tracked Fourier excitation, 14-bit encoder, torque noise)
    writes a fit and a validation CSV into ``out_dir``; :func:`run_repair` identifies the
    baseline, finds the missing effect, and writes the report there. Returns the report with an
    extra ``"truth"`` entry (what was hidden) so a caller can compare.
    """
    from robust_drake.identification.simulated import hidden_effect_case

    os.makedirs(out_dir, exist_ok=True)
    from robust_drake.log import progress_callback

    log = progress_callback(progress)
    fit_csv, val_csv, truth = hidden_effect_case(kind, seed=seed, out_dir=out_dir)
    log(f"simulated experiment: hidden {truth['kind']} on joint {truth['joint']} {truth['parameters']}")
    opts = RepairOptions(robot=truth["robot"], **options)
    rep = run_repair([fit_csv], opts, validate_paths=[val_csv], out_dir=out_dir, progress=log)
    rep["truth"] = {k: v for k, v in truth.items() if k in ("kind", "joint", "parameters", "robot")}
    fmt = lambda xs: "[" + ", ".join(f"{x:.4f}" for x in xs) + "]"  # noqa: E731
    log(f"validation RMS torque error [N m]: baseline {fmt(rep['baseline']['rms_validate'])} -> "
        f"repaired {fmt(rep['final']['rms_validate'])}")
    for e in rep["effects"]:
        log(f"found {e['kind']} on joint {e['joint']}: "
            + ", ".join(f"{k} = {v:.4g}" for k, v in e["parameters"].items() if isinstance(v, float)))
    tmp_json = os.path.join(out_dir, ".report.json.tmp")
    with open(tmp_json, "w") as fh:
        json.dump(rep, fh, indent=2, default=_json_default)
    os.replace(tmp_json, os.path.join(out_dir, "report.json"))  # never a half-written report
    return rep


def effects_from_report(report: dict) -> list:
    """The chosen effects of a repair report as ``[(Effect, parameters), ...]`` (JSON round trip).

    Shape parameters (Stribeck velocity, harmonic, ...) are read back from ``parameters``."""
    from robust_drake.identification.effects import EFFECTS, make_effect

    out = []
    for e in report.get("effects", []):
        cls = EFFECTS[e["kind"]]
        params = dict(e["parameters"])
        shape = {k: params[k] for k in cls.default_shape if k in params and k != "robot"}
        if "robot" in cls.default_shape:
            shape["robot"] = report.get("robot")
        out.append((make_effect(e["kind"], e["joint"], **shape), params))
    return out


def closed_loop_effects(report: dict, sample_period: float = 1e-3) -> list:
    """Plant-side effect block factories ``f(ctx) -> LeafSystem`` for ``ClosedLoopConfig.effects``
    (the repaired model's force-type effects; input ``state`` [+ ``tau``], output
    ``generalized_force``). Plant-modifying effects (rotor_inertia, payload) have no block and are
    left out here: apply them with ``effects.load_plant(robot, effects_from_report(report))``."""
    facts = []
    for eff, params in effects_from_report(report):
        if eff.modifies_plant:
            continue
        facts.append(lambda ctx, eff=eff, params=params: eff.block(ctx.n, params, sample_period=sample_period))
    return facts
