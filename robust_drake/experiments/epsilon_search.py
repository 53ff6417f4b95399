"""The epsilon search of Jaritz & Spong (section 5, section 9, table 1) on the simulated D2R2.

The paper tuned each controller's boundary layer as "the smallest epsilon-values ... possible for the
given trajectories", below which "the chattering will resonate the system", on the CPT without load
("since for this mechanical configuration vibrations are most likely"). Here:

* **Vibration, measured**: the high-frequency fraction of the applied joint torque,
  ``V_j = P_j(f > f_c) / P_j(f > 0)``, the power of ``tau_j - mean`` above ``f_c`` (default 50 Hz)
  relative to its total power (Hann-windowed periodogram of the torque sampled at the control rate,
  first ``skip`` = 0.1 s dropped), ``V = max_j V_j``. The CPT's own torque lives below ~10 Hz; chatter
  of the boundary layer sits near the sample rate, and the flexible D2R2's drive and link modes at
  250-480 Hz, all above f_c. A run **vibrates** when ``V > threshold`` (default 1 %).
* **Search**: epsilon = factor x (table 1 value) on a geometric grid of factors (default 2^(k/2),
  k = -8..4: 1/16 .. 4); all components of a multi-epsilon law (SP2's per-parameter layers, LG+'s
  (eps_M, eps_C)) scale together. The result is the smallest grid epsilon that is vibration-free and
  above which every grid epsilon is vibration-free ("sustained": nothing vibrates above it); None when
  even the largest vibrates. Setting: table 2 (CPT, no load, no fixed friction compensation, whose
  sgn(v) term switches with the noisy velocity and would be counted as chatter), 2500 Hz.
"""

from __future__ import annotations

import numpy as np

from robust_drake.errors import RobustDrakeError

#: JS table 1, the published epsilons on the CPT (SP2: every component; LG+: eps_M, eps_C).
TABLE1 = {"sp1": {"epsilon": 1.0}, "sp2": {"epsilon": 0.5}, "zc": {"epsilon": 25.0},
          "lgplus": {"eps_M": 1.5, "eps_C": 1.0}, "lg": {"eps_M": 1.5, "eps_C": 1.0}}
DEFAULT_FACTORS = tuple(float(2.0 ** (k / 2)) for k in range(-8, 5))
F_CUT = 50.0
THRESHOLD = 0.01
SKIP = 0.1


def vibration_fraction(tau, rate: float, f_cut: float = F_CUT, skip: float = SKIP) -> np.ndarray:
    """Per joint, the fraction of the power of ``tau - mean`` above ``f_cut`` [Hz] (module docstring).

    ``tau`` (K, n) sampled at ``rate`` [Hz]; the first ``skip`` seconds are dropped."""
    tau = np.atleast_2d(np.asarray(tau, dtype=float))
    if tau.shape[0] == 1 and tau.shape[1] > 1:
        tau = tau.T
    k0 = int(round(skip * rate))
    x = tau[k0:]
    if x.shape[0] < 16:
        raise RobustDrakeError(f"vibration measure needs at least 16 samples after {skip} s (got {x.shape[0]})")
    if not 0 < f_cut < rate / 2:
        raise RobustDrakeError(f"f_cut must lie between 0 and the Nyquist frequency {rate / 2:g} Hz (got {f_cut})")
    x = x - x.mean(axis=0)
    P = np.abs(np.fft.rfft(x * np.hanning(len(x))[:, None], axis=0)) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / rate)
    tot = P[1:].sum(axis=0)
    return np.where(tot > 0, P[f > f_cut].sum(axis=0) / np.where(tot > 0, tot, 1.0), 0.0)


def _scaled(controller: str, factor: float) -> dict:
    if controller not in TABLE1:
        raise RobustDrakeError(f"no table-1 epsilon for controller {controller!r}; known: {', '.join(TABLE1)}")
    return {k: v * factor for k, v in TABLE1[controller].items()}


def search_specs(controllers, factors=DEFAULT_FACTORS, *, duration=None, model="rigid", rate=2500.0) -> list[dict]:
    from robust_drake.experiments import jaritz_spong as js

    factors = sorted(float(f) for f in factors)
    if not factors or any(not f > 0 for f in factors):
        raise RobustDrakeError(f"epsilon factors must be positive (got {factors})")
    specs = []
    for c in controllers:
        for f in factors:
            s = js.run_spec(2, c, duration=duration, model=model, rate=rate, controller_params=_scaled(c, f))
            s["factor"] = f
            specs.append(s)
    return specs


def run_vibration(spec: dict) -> dict:
    """One closed loop of the search (module-level, picklable): metrics and the vibration fraction."""
    from robust_drake.diagram import simulate
    from robust_drake.experiments.jaritz_spong import config_for
    from robust_drake.metrics import METRIC_KEYS

    res = simulate(config_for(spec))
    V = vibration_fraction(res.tau, spec["rate"], spec.get("f_cut", F_CUT))
    return {"controller": spec["controller"], "model": spec.get("model", "rigid"), "factor": spec["factor"],
            "params": spec["controller_params"], "vibration": V.tolist(), "diverged": bool(res.diverged),
            **{k: float(res.metrics[k]) for k in METRIC_KEYS}}


def smallest_free(rows: list[dict], threshold: float = THRESHOLD):
    """The row of the smallest factor that does not vibrate and above which nothing vibrates (or None)."""
    rows = sorted(rows, key=lambda r: r["factor"])
    best = None
    for r in reversed(rows):
        if r["diverged"] or max(r["vibration"]) > threshold:
            break
        best = r
    return best


def epsilon_search(controllers=("sp1", "sp2", "zc", "lgplus"), factors=DEFAULT_FACTORS, *, duration=None,
                   models=("rigid",), threshold: float = THRESHOLD, f_cut: float = F_CUT, workers=None,
                   progress=False) -> dict:
    """Run the grid for each controller and model; returns ``{"runs": [...], "results": [...]}`` where
    each result has ``controller``, ``model``, ``epsilon`` (dict or None), ``factor`` (found / table 1),
    ``published`` (table 1) and the tracking error at the found epsilon."""
    from robust_drake.parallel import run_parallel

    if not 0 < threshold < 1:
        raise RobustDrakeError(f"threshold must be a fraction in (0, 1) (got {threshold})")
    specs = []
    for m in models:
        for s in search_specs(controllers, factors, duration=duration, model=m):
            s["f_cut"] = float(f_cut)
            specs.append(s)
    outs = run_parallel(run_vibration, specs, keys=[f"{s['controller']}/{s['model']}/{s['factor']:.4g}" for s in specs],
                        workers=workers, desc="epsilon-search", progress=progress)
    runs = []
    for s, o in zip(specs, outs):
        if o.ok:
            runs.append(o.value)
        else:
            runs.append({"controller": s["controller"], "model": s["model"], "factor": s["factor"],
                         "params": s["controller_params"], "vibration": [float("nan")], "diverged": True,
                         "error": o.error})
    results = []
    for m in models:
        for c in controllers:
            rs = [r for r in runs if r["controller"] == c and r["model"] == m]
            best = smallest_free(rs, threshold)
            results.append({"controller": c, "model": m, "published": TABLE1[c],
                            "epsilon": None if best is None else best["params"],
                            "factor": None if best is None else best["factor"],
                            "vibration": None if best is None else max(best["vibration"]),
                            "error_task": None if best is None else best["error_task"],
                            "grid": [min(r["factor"] for r in rs), max(r["factor"] for r in rs)]})
    return {"threshold": threshold, "f_cut": f_cut, "setting": "table 2: CPT, no load, no friction compensation",
            "runs": runs, "results": results}


from robust_drake.plotting import styled  # noqa: E402 - the shared figure style


@styled
def plot_search(out: dict, directory) -> str:
    """Vibration fraction and |error_task| against epsilon / table 1, one curve per controller and model."""
    import pathlib

    from robust_drake.experiments.jaritz_spong import LABELS
    from robust_drake.plotting import subplots

    d = pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    fig, (a1, a2) = subplots(1, 2, figsize=(11, 4))
    keys = dict.fromkeys((r["controller"], r["model"]) for r in out["runs"])
    for c, m in keys:
        rs = sorted((r for r in out["runs"] if r["controller"] == c and r["model"] == m and "error" not in r),
                    key=lambda r: r["factor"])
        lab = LABELS.get(c, c) + ("" if m == "rigid" else f" [{m}]")
        ls = "-" if m == "rigid" else "--"
        a1.loglog([r["factor"] for r in rs], [max(r["vibration"]) for r in rs], "o" + ls, label=lab)
        a2.semilogx([r["factor"] for r in rs], [r["error_task"] for r in rs], "o" + ls, label=lab)
    a1.axhline(out["threshold"], color="k", lw=0.8)
    a1.axvline(1.0, color="gray", lw=0.8, ls=":")
    a2.axvline(1.0, color="gray", lw=0.8, ls=":")
    a1.set(xlabel="epsilon / table 1", ylabel=f"torque power above {out['f_cut']:g} Hz (fraction)",
           title="vibration measure (line: threshold)")
    a2.set(xlabel="epsilon / table 1", ylabel="|error_task| [m]", title="tracking (JS eq. 58)")
    a1.legend(fontsize=8.5)
    fig.tight_layout()
    path = d / "epsilon_search.png"
    fig.savefig(path, dpi=90)
    return str(path)
