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

plus diagnostics (selection steps, identifiability, residual tests, data summary, notes), the
never-worse outcome (``"verdict": "repaired" | "no_improvement"``, ``"verdict_reason"``,
``"never_worse"``, ``"rejected_effects"`` and ``effects[*].kept/reason/claimed``), ``"setup_change"`` (the
validation run against the fit run's own held-out error, ``diagnostics.setup_change_of``: when flagged the
verdict is ``no_improvement`` and no effect is claimed), ``"joint_names"`` (URDF,
joints numbered from 0 everywhere) and the identified models ``"model"`` / ``"baseline_model"``
(:class:`~robust_drake.identification.model.IdentifiedModel.to_json`), which are what control
takes. The stages are in ``stages.py``; rendering (report.md from the same dict) in ``report.py``.
Validation: the ``validate`` files; without them the last ``HOLDOUT_FRACTION`` of every fit file
(a contiguous tail) is held out, and the report says so.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError, option_name
from robust_drake.model_repair import diagnostics as DG
from robust_drake.model_repair import report as RP
from robust_drake.identification.data import DEFAULT_CUTOFF_HZ, DataWarning
from robust_drake.identification.model import IdentifiedModel
from robust_drake.model_repair.report import json_default as _json_default
from robust_drake.model_repair.report import render_markdown  # noqa: F401  (re-exported)
from robust_drake.model_repair.decisions import LEVEL
from robust_drake.model_repair.selection import MIN_GAIN
from robust_drake.model_repair.stages import HOLDOUT_FRACTION, split_tail, tail_mask  # noqa: F401  (re-exported)


@dataclass
class RepairOptions:
    robot: str
    torque: str = "tau_meas"
    cutoff_hz: float | None = DEFAULT_CUTOFF_HZ
    #: "positions" (differentiate the filtered positions) or "logged" (low-pass the log's qd
    #: columns, for real velocity sensors; identification.data.prepare); the instrument load follows
    velocities: str = "positions"
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
    #: never worse (stages.never_worse, stages.Rule): an effect or the IV switch is kept only if no
    #: joint's validation RMS torque (and replay RMS q) is above the baseline's by more than this
    #: margin (relative) beyond its own sampling spread (paired block test at ``level``, Holm over
    #: joints). It is no longer a threshold on the point estimate (superseded by the test), but the
    #: test's non-inferiority margin; inf switches the rule off
    never_worse_tol: float = 0.01
    #: confidence level of the guards' paired block tests (decisions.py; two-sided intervals,
    #: one-sided tests at (1 - level) / 2 family-wise over the joints)
    level: float = LEVEL
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.validate()

    def validate(self) -> "RepairOptions":
        """Check and normalise every option: the one validation behind ``robust-drake repair`` and
        ``rd.repair`` (each bad value raises :class:`~robust_drake.errors.OptionError` naming the
        option; the command line reports it under its flag, :data:`CLI_FLAGS`). ``kinds`` may be a
        comma-separated string (as ``--effects``); an empty one is refused (None = the library)."""
        from robust_drake.errors import OptionError
        from robust_drake.effects import EFFECTS

        if not isinstance(self.robot, (str, os.PathLike)) or not str(os.fspath(self.robot)).strip():
            raise OptionError("robot", f"must be a robot name or a URDF path, got {self.robot!r}")
        self.robot = os.fspath(self.robot)
        if self.torque not in ("tau_meas", "tau_con"):
            raise OptionError("torque", f"must be 'tau_meas' or 'tau_con', got {self.torque!r}")
        self.velocities = {"differentiated": "positions"}.get(self.velocities, self.velocities) \
            if isinstance(self.velocities, str) else self.velocities
        if self.velocities not in ("positions", "logged"):
            raise OptionError("velocities", f"must be 'positions' (differentiated) or 'logged', got {self.velocities!r}")
        if self.cutoff_hz is not None:
            self.cutoff_hz = _number("cutoff_hz", self.cutoff_hz, "a cut-off in Hz", positive=True)
        if isinstance(self.kinds, str):
            text = self.kinds
            self.kinds = [k.strip() for k in text.split(",") if k.strip()]
            if not self.kinds:
                raise OptionError("kinds", f"is empty ({text!r}): name effect kinds separated by commas "
                                  f"(known: {', '.join(EFFECTS)}), or leave it out for the whole library")
        if self.kinds is not None:
            try:
                kinds = list(self.kinds)
            except TypeError:
                raise OptionError("kinds", f"must be a list of effect kind names, got {self.kinds!r}") from None
            bad = [k for k in kinds if not isinstance(k, str) or k not in EFFECTS]
            if bad:
                raise OptionError("kinds", f"has unknown effect kind(s) {bad}; known: {', '.join(EFFECTS)}")
            self.kinds = kinds
        self.min_gain = _number("min_gain", self.min_gain, "a relative gain (0.05 = 5 %)")
        self.max_effects = _whole("max_effects", self.max_effects)
        self.sigma_rel = _number("sigma_rel", self.sigma_rel, "a relative trust", positive=True)
        self.never_worse_tol = _number("never_worse_tol", self.never_worse_tol, "a relative tolerance",
                                       allow_inf=True)  # inf: the never-worse rule switched off
        self.level = _number("level", self.level, "a confidence level, e.g. 0.95", positive=True)
        if not self.level < 1.0:
            raise OptionError("level", f"must be a confidence level in (0, 1), e.g. 0.95, got {self.level!r}")
        self.replay_horizon = _number("replay_horizon", self.replay_horizon, "a horizon in s", positive=True)
        self.replay_windows = _whole("replay_windows", self.replay_windows, minimum=1)
        for name in ("consistent", "replay", "plots", "weighted", "instruments", "nominal"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise OptionError(name, f"must be True or False, got {getattr(self, name)!r}")
        return self


#: RepairOptions field (or run_repair argument) -> the command line's flag, for messages
CLI_FLAGS = {"robot": "--robot", "torque": "--torque", "cutoff_hz": "--cutoff", "velocities": "--velocities",
             "kinds": "--effects", "min_gain": "--min-gain", "max_effects": "--max-effects",
             "sigma_rel": "--sigma-rel", "level": "--level", "out": "--out", "fit": "FIT.csv", "validate": "--validate",
             "overwrite": "--force"}


def _number(name: str, value, what: str, positive: bool = False, allow_inf: bool = False) -> float:
    """``value`` as a finite float >= 0 (> 0 with ``positive``; +inf too with ``allow_inf``), else
    OptionError naming ``name``."""
    import math

    from robust_drake.errors import OptionError

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise OptionError(name, f"must be a number ({what}), got {value!r}")
    value = float(value)
    if math.isnan(value) or (math.isinf(value) and not (allow_inf and value > 0)) or value < 0 \
            or (positive and value == 0):
        raise OptionError(name, f"must be {'> 0' if positive else '>= 0'} and finite, got {value!r}")
    return value


def _whole(name: str, value, minimum: int = 0) -> int:
    from robust_drake.errors import OptionError

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise OptionError(name, f"must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def _paths(name: str, value, allow_none: bool = False) -> list | None:
    """One path or a sequence of paths as a list of ``str`` (OptionError otherwise)."""
    from robust_drake.errors import OptionError

    if value is None and allow_none:
        return None
    items = [value] if isinstance(value, (str, os.PathLike)) else value
    try:
        items = list(items)
    except TypeError:
        raise OptionError(name, f"must be a file path or a list of file paths, got {value!r}") from None
    bad = [p for p in items if not isinstance(p, (str, os.PathLike)) or not str(os.fspath(p)).strip()]
    if bad or not items:
        raise OptionError(name, f"must be a file path or a non-empty list of file paths, got {value!r}")
    return [os.fspath(p) for p in items]


# physical plausibility of an identified effect, generic + hardware-aware where we know it
def plausibility(kind: str, params: dict, robot: str) -> str:
    from robust_drake.description import describe

    hw = describe(robot)  # hardware facts quoted below come from the robot's description
    motor = hw.motor or "motor"
    gear = hw.geared and hw.gearbox is not None
    p = {k: v for k, v in params.items() if isinstance(v, (int, float))}
    if kind == "load_dependent_friction":
        mu = p.get("load_coefficient", np.nan)
        txt = (f"gear friction growing with transmitted torque, mu = {mu:.3g}; a planetary stage "
               "loses a few to ~20 % of the load torque")
        if gear:
            txt += f" ({motor}: {hw.gear_ratio:g}:1 {hw.gearbox} gear between rotor and joint)"
        return txt + ("" if 0 < mu < 0.5 else "; NOTE: outside the usual 0-0.5 range")
    if kind == "rotor_inertia":
        J = p.get("reflected_inertia", np.nan)
        txt = f"reflected rotor inertia {J:.3g} kg m^2"
        if hw.geared and hw.rotor_inertia is not None:
            gr2 = hw.gear_ratio ** 2
            m, e = f"{hw.rotor_inertia:.3g}".partition("e")[::2]
            ir = f"{m}e{int(e)}" if e else m
            txt += f" ({motor}: gr^2 Ir = {gr2:g} x {ir} = {gr2 * hw.rotor_inertia:.3g} kg m^2)"
        elif hw.torque_interface == "link_side":
            txt += ("; NOTE: the commands are link-side torques closed on joint torque sensors (robot "
                    "description), so the rotors sit inside the maker's torque loop: look for a link-inertia error")
        return txt
    backlash = "" if hw.backlash_deg is None else f"(about {hw.backlash_deg:g} deg on the {motor}) "
    if kind in ("stribeck", "smooth_coulomb", "asymmetric_coulomb"):
        drive = {"qdd": "quasi-direct-drive", "direct": "direct-drive", "geared": "geared"}.get(hw.drive)
        stage = f" with a {hw.gear_ratio:g}:1 {hw.gearbox} stage" if gear else ""
        txt = f"low-velocity friction shape ({kind})"
        if drive:
            txt += f" of a {drive} joint ({hw.motor + stage + ', ' if hw.motor else ''}robot description)"
        return txt + ("" if hw.backlash_deg is None else f"; backlash {backlash}adds a torque dip at every reversal")
    if kind == "presliding_friction":
        Fd, x0 = p.get("presliding_torque", np.nan), p.get("presliding_displacement", np.nan)
        txt = (f"presliding (Dahl) friction: {Fd:.3g} N m of the friction level builds up "
               f"over ~{x0:.3g} rad ({np.degrees(x0):.2g} deg) of motion after "
               "every reversal: compliance of "
               + ("gear teeth and bearings" if hw.geared else "bearings and the structure")
               + " before gross sliding")
        if gear and hw.backlash_deg is not None:
            txt += (f" ({motor}: {hw.gear_ratio:g}:1 {hw.gearbox} stage, about {hw.backlash_deg:g} deg "
                    "backlash taken up at each reversal)")
        return txt
    if kind == "torque_offset":
        return "constant torque bias: current-sensor offset of the driver or an unmodelled static load"
    if kind == "torque_scale":
        g = p.get("gain_error", np.nan)
        return (f"motor-constant error {g:+.1%}: the current-based torque estimate is off by that factor"
                + ("" if abs(g) < 0.3 else "; NOTE: larger than a motor constant usually errs"))
    if kind == "time_delay":
        d = p.get("delay", np.nan)
        from robust_drake.effects import delay_bound

        bound, source = delay_bound(robot)
        return f"delay {d * 1e3:.3g} ms between recorded torque and motion ({source})" + (
            "" if bound is not None and 0 <= d <= bound else "; NOTE: no declared source or above its bound")
    if kind == "spring":
        return "joint-angle proportional torque: cables or a balancing spring"
    if kind == "position_dependent":
        return "position-periodic torque: cogging / torque ripple of the motor"
    if kind == "payload":
        return "extra mass at the tool"
    if kind == "periodic_disturbance":
        return (f"DISTURBANCE, not a property of the arm: a torque periodic in time at "
                f"{p.get('frequency', np.nan):.4g} Hz, amplitude {p.get('amplitude', np.nan):.3g} N m "
                "(a pump, a vibrating base, a neighbouring machine)")
    if kind == "dead_zone":
        return (f"driver dead-zone: commanded torque below {p.get('threshold', np.nan):.3g} N m does not "
                f"reach the joint (share lost {p.get('share', np.nan):.2f})")
    if kind == "friction_drift":
        return "friction changing over the run (warming up: lubricant, seals, brake)"
    if kind == "configuration_dependent":
        return (f"torque depending on other joints' angles ({params.get('terms')}; {p.get('explained_rms', np.nan):.3g} "
                "N m RMS over the fit data): a cable or hose dragged by the other links, or a coupled spring")
    return kind


REPORT_FILES = ("report.md", "report.json")


def check_output_dir(out_dir, overwrite: bool, recovered: list | None = None, cli: bool = True) -> str:
    """Check ``out_dir`` *before* any computation; return its absolute path.

    Refused: an empty name, a path that is a file, a folder that holds an earlier report
    (``report.md`` or ``report.json``) unless ``overwrite``, and a place where no folder can be
    created (probed by creating and removing a temporary folder next to it). Leftovers of a killed
    earlier run are dealt with first (:func:`recover_leftovers`; its lines appended to ``recovered``).
    """
    import tempfile

    opt, force = ("--out", "pass --force") if cli else ("out", "pass overwrite=True")

    text = os.fspath(out_dir)
    if not str(text).strip():
        raise RobustDrakeError(f"{opt} is empty: give the folder for report.md, report.json and the plots")
    path = os.path.abspath(text)
    done = recover_leftovers(path)  # a killed earlier run: restore its report, remove its temporary folders
    if recovered is not None:
        recovered += done
    if os.path.exists(path) and not os.path.isdir(path):
        raise RobustDrakeError(f"{opt} {text} is a file, not a folder; choose a folder name")
    if os.path.isdir(path) and not overwrite:
        held = [f for f in REPORT_FILES if os.path.exists(os.path.join(path, f))]
        if held:
            raise RobustDrakeError(
                f"{text} holds an earlier repair report ({', '.join(held)}); choose another {opt} or "
                f"{force} to replace it")
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
        raise RobustDrakeError(f"cannot write the report to {opt} {text}: "
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


def _exchange(a: str, b: str) -> bool:
    """Swap the paths ``a`` and ``b`` in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``):
    at every instant each name holds a complete folder. False where the system or the file
    system cannot (then the caller falls back to two renames)."""
    import ctypes
    import errno
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), b)


#: leftover names beside ``--out``: ``.<name>.tmp-<pid>-*`` (a report being written) and
#: ``.<name>.old-<pid>-*`` (an earlier report being replaced), ``pid`` = the writing process
_LEFTOVER_KINDS = ("tmp", "old")

def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _leftovers(out: str) -> list[tuple[str, str, int | None]]:
    """(path, kind, writer pid or None) of this output folder's leftovers (see _LEFTOVER_KINDS)."""
    parent, base = os.path.dirname(out), os.path.basename(out)
    found = []
    try:
        names = os.listdir(parent)
    except OSError:
        return []
    for name in names:
        for kind in _LEFTOVER_KINDS:
            prefix = f".{base}.{kind}-"
            if name.startswith(prefix):
                pid_text = name[len(prefix):].split("-", 1)[0]
                found.append((os.path.join(parent, name), kind, int(pid_text) if pid_text.isdigit() else None))
    return sorted(found)


def recover_leftovers(out: str) -> list[str]:
    """Undo what a killed run (SIGKILL, power loss) left beside ``out``; returns one line per action
    (the run that found them lists them among its report's warnings).

    * ``out`` missing and an earlier report set aside (``.old-``): it is put back at ``out``;
    * an earlier report set aside while ``out`` holds a complete one (the kill came after the new
      report was in place): the set-aside copy is removed;
    * temporary folders of a report being written: removed.
    Leftovers of a process still running (another repair writing the same folder) are left alone;
    the lines are also logged as warnings."""
    import shutil

    done = []
    for path, kind, pid in _leftovers(out):
        if pid is not None and pid != os.getpid() and _pid_alive(pid):
            continue
        if kind == "old" and not os.path.exists(out) and os.path.isfile(os.path.join(path, "report.json")):
            os.rename(path, out)
            done.append(f"restored the earlier report at {out} from {os.path.basename(path)} (a run was killed "
                        "while replacing it)")
        elif kind == "old":
            shutil.rmtree(path, ignore_errors=True)
            done.append(f"removed {os.path.basename(path)} beside {out}: the earlier report a killed run had "
                        "already replaced")
        else:
            shutil.rmtree(path, ignore_errors=True)
            done.append(f"removed {os.path.basename(path)} beside {out}: the unfinished report of a killed run")
    if done:
        from robust_drake.log import get_logger

        for line in done:
            get_logger().warning("%s", line)
    return done


def _publish(tmp: str, out: str, keep: list[str]) -> None:
    """Move the complete report folder ``tmp`` into place at ``out``.

    * ``out`` absent: one atomic ``rename``.
    * ``out`` without an earlier report (e.g. a folder holding the input CSVs): the new files are
      moved in one by one (nothing of value is replaced).
    * ``out`` with an earlier report (``overwrite``) and nothing else but this run's inputs
      ``keep``: the inputs are copied into ``tmp``, then ``tmp`` and ``out`` are exchanged in one
      atomic step (:func:`_exchange`) and the old folder, now at ``tmp``, removed -- the old
      report's plots do not survive beside the new one, and a kill at any instant leaves a complete
      report at ``out`` (a leftover folder is removed by the next run, :func:`recover_leftovers`).
      Without an atomic exchange: ``out`` renamed aside, ``tmp`` renamed to ``out``; a kill between
      the two renames is repaired by the next run (the earlier report is put back and the run says so).
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
    if _exchange(tmp, out):
        shutil.rmtree(tmp, ignore_errors=True)  # tmp now holds the earlier report
        return
    old = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.old-{os.getpid()}-", dir=os.path.dirname(out))
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
               overwrite: bool = True, cli: bool = False) -> dict:
    """The whole loop as a sequence of stages (``stages.py``); writes ``report.json``/``report.md``/
    plots into ``out_dir`` when given, rendered from one result (``report.py``).

    The output folder is checked before the computation (:func:`check_output_dir`; with
    ``overwrite=False`` an earlier report there is refused, as the command line does without
    ``--force``), the report is written into a temporary folder beside it and moved into place
    only when complete (:func:`_publish`): a failure part-way leaves an earlier report untouched.
    """
    from robust_drake.identification import input_checks as IC
    from robust_drake.model_repair import stages as S

    from robust_drake.log import StageTimer, progress_callback

    S = StageTimer(S, total=9, desc="repair", enabled=progress is None)  # a bar (terminal, notebook) or a line per stage; -v: timings

    from robust_drake.errors import OptionError

    if not isinstance(options, RepairOptions):
        raise OptionError("options", f"must be a RepairOptions, got {type(options).__name__}")
    opts = options.validate()  # again: fields may have been changed since construction
    fit_paths = _paths("fit", fit_paths)
    validate_paths = _paths("validate", validate_paths, allow_none=True)
    if out_dir is not None and not isinstance(out_dir, (str, os.PathLike)):
        raise OptionError("out", f"must be a folder path (str or os.PathLike), got {out_dir!r}")
    if progress is not None and not callable(progress):
        raise OptionError("progress", f"must be a callable progress(message) or None, got {progress!r}")
    if not isinstance(overwrite, (bool, np.bool_)):
        raise OptionError("overwrite", f"must be True or False, got {overwrite!r}")
    log = progress_callback(progress)  # None: the "robust_drake" logger at INFO
    recovered: list[str] = []
    out_path = check_output_dir(out_dir, overwrite, recovered, cli=cli) if out_dir is not None else None
    IC.check_distinct_files(fit_paths, validate_paths)
    _check_robot_urdf(opts.robot)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        inp = S.load_inputs(fit_paths, validate_paths, opts, log)
        base = S.fit_baseline(inp, opts, log)
        setup = _setup_change(inp, base, log, opts.level)  # the validation run against the fit run's own held-out error
        if validate_paths:  # validation data that the fitted baseline does not carry over to
            inp.warnings += IC.transfer_check(inp.val.tau, inp.val.tau - base.val_residual, base.fit.rms)
        est = S.choose_estimator(inp, base, opts, log)
        sel = S.select_effects(inp, base, est, opts, log)
        # judged on the joint the selection measured the gain on (before torque_scale is moved)
        sel, gain_drops = S.validated_gain_guard(inp, base, est, sel, opts, log)
        sel = S.resolve_torque_scale(inp, base, est, sel, opts, log)
        est, sel, guard = S.never_worse(inp, base, est, sel, opts, log, tol=opts.never_worse_tol)
        guard.dropped[:0] = gain_drops
        est, sel, fin, cons, replay_out = S.replay_guard(inp, base, est, sel, guard, opts, log)
        nominal = S.compare_nominal(inp, sel, fin, guard, opts, log, base)
    _rate_plausibility(fin.effects_out, opts.robot)
    setup = _setup_explained(inp, base, sel, fin, setup, log, opts.level)
    warn_msgs = list(dict.fromkeys(recovered + inp.warnings
                                   + sorted({str(w.message) for w in caught})))
    urdf_better = urdf_model_validates_better(nominal, fin.val_residual, guard.tolerance)
    if urdf_better:
        warn_msgs.append(urdf_better)
    if setup["flagged"]:
        warn_msgs.append(DG.setup_change_text(setup, inp.joint_names))
    warn_msgs = RP.once(warn_msgs)
    result = RP.RepairResult(opts, inp, base, est, sel, guard, fin, nominal, cons, replay_out, warn_msgs, setup)
    report = RP.build_report(result)
    inp.cf.release(result.selection.chosen)  # the candidates' columns are not needed for plots and files
    if out_path is not None:
        _write_report(report, result, out_path, fit_paths, validate_paths)
    return report


def _setup_change(inp, base, log, level: float | None = None) -> dict:
    """``diagnostics.setup_change_of`` on the baseline (computed once, before any effect)."""
    sc = DG.setup_change_of(inp.cf, base.weights, base.fit.residual, inp.val, base.val_residual, level=level)
    log("setup change between fit and validation: " + ("FLAGGED on joint(s) " + ", ".join(str(j + 1) for j in sc["joints"])
                                                       if sc["flagged"] else "not flagged"))
    return sc


def _setup_explained(inp, base, sel, fin, setup: dict, log, level: float | None = None) -> dict:
    """``diagnostics.setup_explained``: a flagged fit/validation mismatch re-judged with the kept
    effects on both sides (the repaired model's validation residual ``fin.val_residual``), on the
    baseline test's rows and blocks (split and correlation time from the baseline residual)."""
    if not setup.get("flagged") or not sel.chosen or fin.val_residual is None:
        return setup
    sc = DG.setup_explained(setup, inp.cf, sel.weights, base.fit.residual, inp.val, fin.val_residual, sel.chosen,
                            level=level)
    if not sc["flagged"]:
        log("setup change: the mismatch on joint(s) " + ", ".join(str(j + 1) for j in sc["baseline_joints"])
            + " is explained by the kept effects (the repaired model validates as well as it fits): not flagged")
    return sc


def urdf_model_validates_better(nominal, val_residual, tol: float) -> str | None:
    """A warning when the URDF's rigid body (friction and kept effects refitted on it, the nominal
    comparison's "URDF-model validate") validates better than the repaired model on every joint by
    more than ``tol`` (the never-worse tolerance): the free fit's rigid-body parameters then do not
    carry over to the validation data, and the verdict, which compares with the free baseline,
    would not say so. None otherwise (or without a nominal comparison / validation data)."""
    if not nominal or val_residual is None or len(val_residual) == 0:
        return None
    urdf = np.asarray(nominal["rms_validate"], float)
    repaired = np.sqrt(np.mean(np.asarray(val_residual, float) ** 2, axis=0))
    if not (urdf.shape == repaired.shape and np.all(urdf * (1.0 + tol) < repaired)):
        return None
    return (f"the URDF's rigid-body parameters (friction and kept effects refitted on them) validate better than "
            f"the repaired model on every joint: {np.round(urdf, 4).tolist()} vs {np.round(repaired, 4).tolist()} "
            f"N m RMS; the free fit's parameter shift (chi2 {nominal['chi2']:.1f}) does not carry over to the "
            "validation data: consider keeping the URDF's parameters")


def _rate_plausibility(rows: list[dict], robot) -> None:
    """Each kept effect's ``plausibility`` text (:func:`plausibility`)."""
    for row in rows:
        row["plausibility"] = plausibility(row["kind"], row["parameters"], robot)
        if row["source"] == "parameter_shift":
            row["plausibility"] += (" (inside the rigid-body span: named from the base-parameter shift against "
                                    "the URDF; errors are URDF-only vs URDF + this effect)")


def _write_report(report: dict, result, out_path: str, fit_paths, validate_paths) -> None:
    """Plots + report files into a temporary folder beside ``out_path``, then :func:`_publish`."""
    import shutil
    import tempfile

    opts, inp = result.opts, result.inputs
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out_path)}.tmp-{os.getpid()}-", dir=os.path.dirname(out_path))
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the report folder is not
        if opts.plots:
            report["plots"] = RP.write_plots(tmp, result)
            if report["estimator"].get("hausman") and fit_paths_are_files(fit_paths):
                from robust_drake.identification import instruments as IV

                fc = inp.fit.filter.cutoff_hz
                icache = result.estimator.icache
                # the fit columns and instruments at fc are the repair's own when fit = the whole files
                reuse = (inp.cf, icache) if inp.fit is inp.data and icache is not None else None
                sweep = IV.cutoff_sweep(fit_paths, opts.robot, inp.regressor, [0.5 * fc, 0.75 * fc, fc, 1.5 * fc],
                                        torque=opts.torque, weights=result.selection.weights, n_joints=inp.fit.n,
                                        reuse=reuse)
                report["estimator"]["cutoff_sweep"] = RP.strict(sweep)
                IV.plot_cutoff_sweep(sweep, os.path.join(tmp, "estimator_cutoff.png"))
                report["plots"].append("estimator_cutoff.png")
        write_report_files(report, tmp)
        _publish(tmp, out_path, _inputs_inside(list(fit_paths) + list(validate_paths or []), out_path))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


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


def fit_paths_are_files(paths) -> bool:
    return all(isinstance(p, (str, os.PathLike)) and os.path.isfile(p) for p in paths)


def attach_truth(rep: dict, truth: dict, out_dir: str | None) -> dict:
    """Simulated data: put what the simulator was given (``truth``: ``kind``, ``joint``,
    ``parameters``, optionally ``friction`` = {"coulomb", "viscous"}) into the report as
    ``rep["truth"]`` and rewrite report.json / report.md in ``out_dir`` (report.md then shows the
    truth beside what was found, ``report._md_truth``)."""
    rep["truth"] = truth
    if out_dir is not None and os.path.isfile(os.path.join(out_dir, "report.json")):
        write_report_files(rep, out_dir)
    return rep


def effects_from_report(report: dict) -> list:
    """The chosen effects of a repair report as ``[(Effect, parameters), ...]`` (via
    :class:`~robust_drake.identification.model.IdentifiedModel`)."""
    return IdentifiedModel.from_report(report).effect_terms()
