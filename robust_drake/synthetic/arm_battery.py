"""The issue-21 battery: hidden effects and setup changes on six- and seven-axis arms.

Builds on :func:`robust_drake.synthetic.simulated.simulate_experiment` (the true plant: URDF,
baseline Coulomb + viscous friction, library effects from :mod:`effects` with their Drake
blocks, PD tracking of a random Fourier reference) and on :func:`battery.described_copy`.  What
is new here: arms of UR5 class (``robots/ur5``) and the 7-joint ``serial7`` / ``panda``
(:data:`ARM_SIM`), logs at 500 Hz and 100 Hz, current-based torque noise, effect magnitudes set
relative to that noise, and runs whose fit and validation plants differ (setup changes).

Torque noise model (current-based torques, a motor current times a torque constant): the
logged torque of joint j at sample k is

    tau_log[k, j] = tau[k, j] + e[k, j],   e ~ N(0, sigma[k, j]^2),
    sigma[k, j]   = rel |tau[k, j]| + floor_j                                   (1)

with ``rel`` (dimensionless, a few %: the current sensor's gain ripple) and ``floor_j`` [N m]
(quantisation and electrical noise of the current loop) per arm in :data:`ARM_SIM`.  "k times
the noise" of joint j means k times its noise RMS over the fit run of the no-effect case,
``sigma_rms_j = sqrt(mean_k sigma[k, j]^2)`` (:func:`noise_rms`).

Cases (:data:`CASES`; ``generate`` returns ``(fit_paths, validate_paths, truth)``):

- ``none``: the baseline arm only;
- ``rotor_inertia``: the fit model is the arm's URDF without the shoulder joint's
  ``drake:rotor_inertia`` (:func:`without_rotor`); the plant adds that reflected inertia back;
- ``load_dependent_friction``: mu |tau| sign(qd) on the shoulder joint;
- ``cogging_3x`` / ``cogging_10x``: a position-periodic torque (harmonic 8 per rev) on a wrist
  joint, amplitude 3 / 10 times that joint's noise RMS;
- ``two_effects``: load-dependent friction on the shoulder and 10x cogging on the wrist;
- ``payload_validation_only``: a point mass at the tool in the validation run only (a setup
  change; nothing is to be claimed, the mismatch is to be flagged);
- ``sensor_offset_change``: a torque-sensor offset on the elbow joint that differs between the
  fit and the validation run (re-zeroing; a setup change);
- ``time_delay``: a delay of the command shared by all joints, repaired against a copy of the
  arm whose description declares a bus (:data:`BUS`), as ``battery.time_delay_bus``.

:func:`library_case` gives one library kind at ``level`` times the noise (the calibration's
detection rates, ``benchmarks/calibration.py``): the key parameter is set so that the effect's
torque RMS on its joint, evaluated on the no-effect run's true motion (seed :data:`SCALE_SEED`,
the same magnitude for every seed), is ``level`` sigma_rms.
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np
import pandas as pd

from robust_drake.errors import RobustDrakeError
from robust_drake.synthetic.simulated import HIDDEN_CASES, simulate_experiment

#: per arm: simulation settings (baseline friction [N m], [N m s/rad]; excitation), the noise
#: model (1) (``rel``, ``floor`` [N m]) and the joints the cases put their effects on
ARM_SIM = {
    "ur5": dict(coulomb=(1.0, 1.0, 0.6, 0.2, 0.2, 0.2), viscous=(0.5, 0.5, 0.3, 0.08, 0.08, 0.08),
                rel=0.02, floor=(0.15, 0.15, 0.1, 0.03, 0.03, 0.03),
                excitation=dict(amplitude=(0.8, 0.6, 0.8, 1.0, 1.0, 1.0), offset=(0.0, -1.57, 1.57, -1.57, -1.57, 0.0),
                                torque_limit=np.array([150.0, 150.0, 150.0, 28.0, 28.0, 28.0])),
                shoulder=1, elbow=2, wrist=4, payload=2.0),
    "serial7": dict(coulomb=0.2, viscous=0.04, rel=0.02, floor=0.03,
                    excitation=dict(amplitude=0.6, torque_limit=300.0),
                    shoulder=1, elbow=3, wrist=5, payload=2.0),
    "panda": dict(coulomb=0.2, viscous=0.04, rel=0.02, floor=0.03,
                  excitation=dict(amplitude=0.4, offset=(0.0, 0.0, 0.0, -1.8, 0.0, 1.8, 0.0),
                                  torque_limit=np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])),
                  shoulder=1, elbow=3, wrist=5, payload=2.0),
}
RATES_HZ = (500.0, 100.0)
DURATION = 10.0  # s per run (one period of the 0.1 Hz Fourier reference)
COGGING_HARMONIC = 8
LOAD_MU = 0.05
#: sensor offset of the fit / validation run, in multiples of the joint's noise floor
OFFSETS = (5.0, -5.0)
DELAY = 0.012  # s
BUS = dict(bus="RS-485", bus_latency=0.008)  # delay bound 2 L = 16 ms (effects.delay_bound)
CASES = ("none", "rotor_inertia", "load_dependent_friction", "cogging_3x", "cogging_10x",
         "two_effects", "payload_validation_only", "sensor_offset_change", "time_delay")
#: setup changes: nothing is to be claimed, the fit/validation mismatch is to be flagged
SETUP_CHANGES = ("payload_validation_only", "sensor_offset_change")
#: bounds on library_case's key parameter: a delay within the declared bus bound (2 L, the
#: repair's ``effects.delay_bound``), a reflected inertia below the arm's largest M_jj scale,
#: a motor-constant error within the library's +-50 %
HIDDEN_BOUNDS = {"time_delay": 2.0 * BUS["bus_latency"], "torque_scale": 0.5, "load_dependent_friction": 1.0}
#: the no-effect run whose motion and noise set the magnitude of every seed's library_case
SCALE_SEED = 0
#: library kinds whose key parameter scales the effect's torque linearly (library_case)
LINEAR_KINDS = ("stribeck", "smooth_coulomb", "load_dependent_friction", "position_dependent",
                "torque_offset", "torque_scale", "rotor_inertia", "spring", "time_delay")


def current_noise(tau: np.ndarray, rel: float, floor, rng) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1): (noise e [N m], its std sigma [N m]), arrays like ``tau`` (N, n)."""
    tau = np.asarray(tau, float)
    sigma = rel * np.abs(tau) + np.broadcast_to(np.asarray(floor, float), tau.shape[1:])
    return rng.standard_normal(tau.shape) * sigma, sigma


def _sim(robot: str):
    if robot not in ARM_SIM:
        raise RobustDrakeError(f"no arm-battery settings for {robot!r}; known: {', '.join(ARM_SIM)}")
    return ARM_SIM[robot]


def simulate_run(plant_robot, effects, arm: str, seed: int, rate_hz: float, duration: float,
                 out_csv: str | None = None):
    """One run of ``plant_robot`` (the arm ``arm``'s settings) with ``effects``: the log with the
    current-based noise (1) on the torques (written to ``out_csv``) and the true signals
    (``q, qd, tau, t`` and ``sigma``, the noise std per sample)."""
    cfg = _sim(arm)
    df, true = simulate_experiment(plant_robot, effects, duration=duration, rate_hz=rate_hz, seed=seed,
                                   excitation=dict(cfg["excitation"]), torque_noise_std=0.0,
                                   coulomb=cfg["coulomb"], viscous=cfg["viscous"], return_result=True)
    n = true["tau"].shape[1]
    e, sigma = current_noise(true["tau"], cfg["rel"], cfg["floor"], np.random.default_rng(30_000 + seed))
    cols = [f"tau{j + 1}" for j in range(n)]
    df[cols] = df[cols].to_numpy() + e
    true["sigma"] = sigma
    if out_csv is not None:
        os.makedirs(os.path.dirname(os.path.abspath(out_csv)), exist_ok=True)
        df.to_csv(out_csv, index=False, float_format="%.10g")
    return df, true


@functools.lru_cache(maxsize=32)
def _none_run(arm: str, seed: int, rate_hz: float, duration: float):
    return simulate_run(arm, (), arm, seed, rate_hz, duration)[1]


def noise_rms(arm: str, seed: int = 0, rate_hz: float = 500.0, duration: float = DURATION) -> np.ndarray:
    """sigma_rms_j [N m] of eq. (1) over the no-effect fit run (seed ``seed``), per joint."""
    return np.sqrt(np.mean(_none_run(arm, seed, rate_hz, duration)["sigma"] ** 2, axis=0))


def unit_torque_rms(kind: str, joint, shape: dict, arm: str, seed: int, rate_hz: float,
                    duration: float) -> np.ndarray:
    """Per joint, the RMS torque [N m] of the effect ``kind`` with its key parameter 1 (shape
    ``shape``, other parameters as ``simulated.HIDDEN_CASES``) on the no-effect run's true motion
    (columns of :meth:`Effect.evaluate_columns` times :meth:`Effect.coef_from_parameters`)."""
    from robust_drake.effects import make_effect, time_derivative

    tr = _none_run(arm, seed, rate_hz, duration)
    q, qd, tau, t = tr["q"], tr["qd"], tr["tau"], tr["t"]
    qdd = time_derivative(t, qd)
    eff = make_effect(kind, joint, **shape)
    case = HIDDEN_CASES[kind]
    n = q.shape[1]
    params = {**case["parameters"], **shape, case["key"]: 1.0}
    cols = eff.evaluate_columns(q, qd, qdd, tau, time_derivative(t, tau))
    return np.sqrt(np.mean((cols @ eff.coef_from_parameters(params, n)) ** 2, axis=0))


def _truth(kind, joint, params, key, rtol=0.10, **more) -> dict:
    return {"kind": kind, "joint": joint, "parameters": dict(params), "key": key, "rtol": rtol, **more}


def _pair(plant_fit, plant_val, eff_fit, eff_val, arm, out_dir, tag, rate_hz, duration, seed):
    """Fit run (seed) and validation run (seed + 1, another motion) as CSVs in ``out_dir``."""
    paths = []
    for role, plant, effs, s in (("fit", plant_fit, eff_fit, seed), ("validate", plant_val, eff_val, seed + 1)):
        p = os.path.join(out_dir, f"{tag}_{role}.csv")
        simulate_run(plant, effs, arm, s, rate_hz, duration, out_csv=p)
        paths.append(p)
    return [paths[0]], [paths[1]]


def library_case(arm: str, kind: str, level: float, joint: int | None = None, out_dir: str = ".",
                 rate_hz: float = 500.0, duration: float = DURATION, seed: int = 0):
    """One library ``kind`` (:data:`LINEAR_KINDS`) at ``level`` x the noise RMS on ``joint``
    (default: the wrist for ``position_dependent``, the shoulder for the other per-joint kinds;
    shared kinds keep ``joint=None``):
    (fit_paths, validate_paths, truth).  A shared kind (time delay) is scaled on the joint where
    its torque is largest relative to the noise."""
    if kind not in LINEAR_KINDS:
        raise RobustDrakeError(f"library_case: {kind!r} is not one of {', '.join(LINEAR_KINDS)}")
    cfg, case = _sim(arm), HIDDEN_CASES[kind]
    os.makedirs(out_dir, exist_ok=True)
    if joint is None and case["joint"] is not None:  # cogging on a wrist, the rest on the loaded shoulder
        joint = cfg["wrist"] if kind == "position_dependent" else cfg["shoulder"]
    shape = {k: v for k, v in case["parameters"].items() if k != case["key"] and k != "phase"}
    if kind == "position_dependent":
        shape = {"harmonic": COGGING_HARMONIC}
    sig = noise_rms(arm, SCALE_SEED, rate_hz, duration)  # one scale for every seed of a level
    unit = unit_torque_rms(kind, joint, shape, arm, SCALE_SEED, rate_hz, duration)
    ratio = unit / sig
    jj = int(np.argmax(ratio)) if joint is None else joint
    value = math.copysign(level / ratio[jj], case["parameters"][case["key"]])
    bound = HIDDEN_BOUNDS.get(kind, math.inf)
    if abs(value) > bound:
        raise RobustDrakeError(f"{kind} at {level:g}x the noise on {arm} needs {case['key']} = {value:.4g}, "
                               f"beyond its physical bound {bound:g} (not generated)")
    params = {**{k: v for k, v in case["parameters"].items() if k != case["key"]}, **shape, case["key"]: value}
    plant, fit_robot = arm, arm
    if kind == "rotor_inertia":
        plant = fit_robot = without_rotor(arm, joint, os.path.join(out_dir, f"{arm}_no_rotor{joint}.urdf"))
    if kind == "time_delay":
        from robust_drake.synthetic.battery import described_copy
        fit_robot = described_copy(arm, out_dir, **BUS)
    effs = [(kind, joint, params)]
    fits, vals = _pair(plant, plant, effs, effs, arm, out_dir, f"{kind}_{level:g}x", rate_hz, duration, seed)
    return fits, vals, _truth(kind, joint, params, case["key"], level=level, noise_rms=float(sig[jj]),
                              fit_robot=fit_robot, robot=arm, case=f"{kind}@{level:g}x")


def _setup_change(arm, case, out_dir, rate_hz, duration, seed):
    cfg = _sim(arm)
    if case == "payload_validation_only":
        eff_fit, eff_val = [], [("payload", None, {"mass": cfg["payload"], "robot": arm})]
        truth = {"kind": None, "joint": None, "parameters": {}, "setup_change": "payload",
                 "validation_payload": cfg["payload"]}
    else:
        j = cfg["elbow"]
        floor = np.asarray(cfg["floor"], float)
        o_fit, o_val = (o * float(floor if floor.ndim == 0 else floor[j]) for o in OFFSETS)
        eff_fit, eff_val = ([("torque_offset", j, {"offset": o})] for o in (o_fit, o_val))
        truth = {"kind": None, "joint": j, "parameters": {}, "setup_change": "sensor_offset",
                 "offset_fit": o_fit, "offset_validate": o_val}
    fits, vals = _pair(arm, arm, eff_fit, eff_val, arm, out_dir, case, rate_hz, duration, seed)
    truth.update(case=case, robot=arm, fit_robot=arm)
    return fits, vals, truth


def generate(arm: str, case: str, out_dir: str, rate_hz: float = 500.0, duration: float = DURATION,
             seed: int = 0):
    """Write the case's logs into ``out_dir``: (fit_paths, validate_paths, truth) (see the module
    docstring; ``truth['effects']`` lists every hidden effect as (kind, joint, parameters))."""
    cfg = _sim(arm)
    if case not in CASES:
        raise RobustDrakeError(f"unknown arm-battery case {case!r}; known: {', '.join(CASES)}")
    os.makedirs(out_dir, exist_ok=True)
    kw = dict(out_dir=out_dir, rate_hz=rate_hz, duration=duration, seed=seed)
    if case in SETUP_CHANGES:
        return _setup_change(arm, case, out_dir, rate_hz, duration, seed)
    if case == "none":
        fits, vals = _pair(arm, arm, [], [], arm, out_dir, case, rate_hz, duration, seed)
        return fits, vals, {"kind": None, "joint": None, "parameters": {}, "effects": [], "case": case,
                            "robot": arm, "fit_robot": arm}
    if case == "rotor_inertia":
        plant = without_rotor(arm, cfg["shoulder"], os.path.join(out_dir, f"{arm}_no_rotor.urdf"))
        params = {"reflected_inertia": _reflected_inertia(arm)}
        effs = [("rotor_inertia", cfg["shoulder"], params)]
        fits, vals = _pair(plant, plant, effs, effs, arm, out_dir, case, rate_hz, duration, seed)
        t = _truth("rotor_inertia", cfg["shoulder"], params, "reflected_inertia", fit_robot=plant)
    elif case == "load_dependent_friction":
        params = {"load_coefficient": LOAD_MU}
        effs = [("load_dependent_friction", cfg["shoulder"], params)]
        fits, vals = _pair(arm, arm, effs, effs, arm, out_dir, case, rate_hz, duration, seed)
        t = _truth("load_dependent_friction", cfg["shoulder"], params, "load_coefficient", fit_robot=arm)
    elif case in ("cogging_3x", "cogging_10x", "two_effects"):
        level = 3.0 if case == "cogging_3x" else 10.0
        fits, vals, t = library_case(arm, "position_dependent", level, joint=cfg["wrist"], **kw)
        if case == "two_effects":
            p2 = {"load_coefficient": LOAD_MU}
            effs = [("position_dependent", cfg["wrist"], t["parameters"]),
                    ("load_dependent_friction", cfg["shoulder"], p2)]
            fits, vals = _pair(arm, arm, effs, effs, arm, out_dir, case, rate_hz, duration, seed)
            t["also"] = [_truth("load_dependent_friction", cfg["shoulder"], p2, "load_coefficient")]
    else:  # time_delay
        params = {"delay": DELAY}
        effs = [("time_delay", None, params)]
        fits, vals = _pair(arm, arm, effs, effs, arm, out_dir, case, rate_hz, duration, seed)
        from robust_drake.synthetic.battery import described_copy
        t = _truth("time_delay", None, params, "delay", fit_robot=described_copy(arm, out_dir, **BUS))
    t.update(case=case, robot=arm)
    t["effects"] = [(x["kind"], x["joint"], x["parameters"]) for x in [t] + t.get("also", [])]
    return fits, vals, t


def without_rotor(arm: str, joint: int, out_path: str) -> str:
    """Copy of ``arm``'s URDF whose ``joint`` (0-based; its transmission names ``joint<j+1>``)
    has no ``drake:rotor_inertia``; the other joints keep theirs.  (Stripping every joint, as
    ``simulated.strip_rotor_inertia`` does, leaves the UR5's wrist 3 with 1.3e-4 kg m^2 of link
    inertia against 0.2 N m of tanh(qd / 0.01 rad/s) Coulomb friction: a 5 us time constant on
    which the error-controlled integrator crawled, 7 min for one 10 s run.)  Returns the path."""
    import re

    from robust_drake.effects import resolve_robot_path

    text = open(resolve_robot_path(arm)).read()
    pat = re.compile(r'(<joint name="joint%d"/>.*?)\s*<drake:rotor_inertia[^>]*/>' % (joint + 1), re.S)
    new, k = pat.subn(r"\1", text, count=1)
    if k != 1:
        raise RobustDrakeError(f"{arm}: no drake:rotor_inertia on the transmission of joint{joint + 1}")
    with open(out_path, "w") as fh:
        fh.write(new)
    return out_path


def _reflected_inertia(arm: str) -> float:
    """The reflected rotor inertia [kg m^2] of the arm's description (rotor x ratio^2), else the
    ``HIDDEN_CASES`` value scaled as the 7-joint battery's (x 20)."""
    from robust_drake.description import describe

    d = describe(arm)
    if d.rotor_inertia and d.gear_ratio:
        return float(d.rotor_inertia * d.gear_ratio ** 2)
    return 20.0 * HIDDEN_CASES["rotor_inertia"]["parameters"]["reflected_inertia"]


def claimed(rep: dict) -> list[tuple]:
    """(kind, joint, confidence) of every effect a repair report accepted and claims (an effect
    kept while the validation run does not match the fit run, ``setup_change``, is not claimed)."""
    return [(e["kind"], e.get("joint"), e.get("confidence")) for e in rep.get("effects", []) if e.get("claimed", True)]


def matches(rep: dict, truth: dict) -> dict:
    """Per hidden effect of ``truth['effects']``: was its kind named on its joint, and the
    relative error of its key parameter (None if not named)."""
    from robust_drake.synthetic.battery import _estimate

    out = []
    for kind, joint, params in truth.get("effects", []):
        t = {"kind": kind, "joint": joint, "key": HIDDEN_CASES[kind]["key"]}
        e, est = _estimate(rep, t)
        true = params.get(t["key"])
        out.append({"kind": kind, "joint": joint, "found": e is not None, "estimate": est, "true": true,
                    "rel_error": None if est is None else abs(est - true) / abs(true)})
    return {"effects": out, "others": [c for c in claimed(rep)
                                       if not any(c[0] == k and (j is None or c[1] == j)
                                                  for k, j, _ in truth.get("effects", []))]}


def read_log(path: str) -> pd.DataFrame:
    """A battery CSV (``t, q1..qn, tau1..taun``)."""
    return pd.read_csv(path)
