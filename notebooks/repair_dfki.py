# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Repairing a model with measured data: the DFKI double pendulum
#
# The loop of `robust-drake repair`, step by step, on real measurements of the DFKI RIC double
# pendulum, design C.1 (two AK80-6 quasi-direct-drive motors, 6:1 gears, in a vertical plane):
#
# 1. read and filter the records (zero-phase Butterworth on q and tau, central differences);
# 2. fit the baseline: Drake-derived base parameters of the URDF + Coulomb + viscous friction;
# 3. look at the residual against the state, time, frequency and velocity reversals;
# 4. let forward selection try every effect of the library on held-out error;
# 5. test the estimator itself for errors in variables (least squares vs instrumental variables);
# 6. compare the validation error (closed-loop swing-ups) and the replayed motion before and after.
#
# Without the shared data folder the notebook runs the same loop on the built-in simulated
# experiment (an arm with a hidden Stribeck effect).

# %%
# %matplotlib inline
import glob
import os
import tempfile
import warnings

import matplotlib.pyplot as plt  # noqa: F401 - the inline backend shows the returned Figures
import numpy as np
from IPython.display import display

import robust_drake as rd
# the steps inside rd.repair, for this walk-through
from robust_drake.model_repair import residual as R
from robust_drake.identification.data import DataWarning, load
from robust_drake.identification.least_squares import load_regressor
from robust_drake.model_repair.selection import ColumnCache, fit_model, predict_tau
from robust_drake.synthetic.simulated import hidden_effect_case

warnings.simplefilter("ignore", DataWarning)
SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
OUT = os.environ.get("ROBUST_DRAKE_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="repair_")
C1 = "../shared/data/dfki_double_pendulum/design_C1"
if not os.path.isdir(C1):  # notebooks run with the repository root as working directory
    C1 = os.path.join(os.getcwd(), "..", "shared", "data", "dfki_double_pendulum", "design_C1")
HAVE_DATA = os.path.isdir(C1)
print("DFKI data found" if HAVE_DATA else "no shared data: using the simulated experiment")

# %% [markdown]
# ## 1-2. Data and the baseline fit
# Fit: the open-loop runs. Validation: the two swing-ups. The command's defaults: the driver's
# torque estimate (`tau_meas`) and an 8 Hz cut-off.

# %%
if HAVE_DATA:
    robot = "dfki_double_pendulum_c1"
    fit_files = sorted(glob.glob(os.path.join(C1, "20230629-143*.csv")))
    val_files = sorted(glob.glob(os.path.join(C1, "20230629-154*.csv")))
    torque = "tau_meas"
else:
    f, v, truth = hidden_effect_case("stribeck", out_dir=OUT)
    robot, fit_files, val_files, torque = truth["robot"], [f], [v], "tau_meas"

fit = load(fit_files, robot=robot, torque=torque, cutoff_hz=8.0)
val = load(val_files, robot=robot, torque=torque, cutoff_hz=8.0)
reg = load_regressor(robot)
print(reg)
cf, cv = ColumnCache(fit, reg), ColumnCache(val, reg)
base, _ = fit_model(cf, [])
r_val = val.tau - predict_tau(cv, [], base.theta)
for name, value, se in zip(base.names, base.theta, base.se):
    print(f"{name:>36s} = {value: .5f} +- {se:.5f}")
print("baseline RMS fit", np.round(base.rms, 4), "validate", np.round(np.sqrt(np.mean(r_val**2, 0)), 4))

# %% [markdown]
# ## 3. The residual
# Binned means (thick lines) show structure a person can read: dependence on angle, velocity,
# acceleration, torque; the spectrum; the mean residual around every velocity reversal.

# %%
display(R.residual_figure(fit, base.residual, "baseline residual (fit data)"))
ana = R.analyse(fit, base.residual)
print("unexplained structure:", ana["unexplained_structure"], ana["where"][:3])

# %% [markdown]
# ## The estimator: do the parameters depend on the cut-off?
# If the regressor columns carried only what the torque causes, the least-squares parameters
# would not care how much high-frequency content the filter lets through. On C.1 they shrink as
# the cut-off rises (attenuation: errors in the variables), while instrumental variables (the
# same columns low-passed at half the cut-off as instruments) move much less.

# %%
from robust_drake.identification.instruments import cutoff_sweep, cutoff_sweep_figure  # noqa: E402

cutoffs = [4.0, 8.0] if SHORT else [3.0, 4.0, 6.0, 8.0, 10.0, 12.0]
sweep = cutoff_sweep(fit_files, robot, reg, cutoffs, torque=torque)
display(cutoff_sweep_figure(sweep))

# %% [markdown]
# ## 4-6. Selection, estimator and before/after
# The whole loop in one call, `rd.repair` (what `robust-drake repair` runs).

# %%
rep = rd.repair(fit_files, robot=robot, validate=val_files, out=os.path.join(OUT, "report"), torque=torque,
                cutoff_hz=8.0, replay=not SHORT, overwrite=True, progress=print)
for s in rep["selection"]["steps"]:
    print(f"step {s['step']}: {s['label']:<45s} {s['reason']}")
print("validation RMS before", np.round(rep["baseline"]["rms_validate"], 4),
      "after", np.round(rep["final"]["rms_validate"], 4))
for e in rep["effects"]:
    print(e["kind"], e["joint"], e["parameters"], "--", e["plausibility"])
print("estimator:", rep["estimator"]["method"], "Hausman", rep["estimator"].get("hausman"))
if rep["replay"]["after"]:
    print("replay RMS q error before", np.round(rep["replay"]["before"]["rms_q"], 4),
          "after", np.round(rep["replay"]["after"]["rms_q"], 4))

# %%
rd.repair_figure(rep)  # RMS torque residual per joint, baseline vs repaired, fit and validation data

# %% [markdown]
# The report (`report.md`, `report.json`, plots) is in `OUT/report`. On a simulated experiment the
# hidden effect is found with its parameter:

# %%
if not SHORT:
    f, v, truth = hidden_effect_case("stribeck", out_dir=os.path.join(OUT, "demo"))
    demo = rd.repair(f, robot=truth["robot"], validate=v, out=os.path.join(OUT, "demo", "report"), overwrite=True)
    print(truth, [(e["kind"], e["joint"], e["parameters"]) for e in demo["effects"]])
