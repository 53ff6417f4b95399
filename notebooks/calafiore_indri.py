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
# # Calafiore & Indri: identification -> confidence ellipsoid -> robust control
#
# The whole chain of the paper (seeds/000) on the IMI SCARA, simulated:
#
# 1. an exciting trajectory, exact torques from the section 5 regressor and noise within the
#    paper's bounds on torques and accelerations; n_m samples chosen D-optimally;
# 2. the linearised LFR uncertainty model of section 5 and the normal equations (eq. 4 product
#    rule; note H != 0);
# 3. the minimal-trace ellipsoid E(P, theta0) containing every least-squares solution (SDP through
#    Drake's MathematicalProgram), certified by sampling Delta;
# 4. nominal (eq. 6) vs robust (eq. 15) control on filtered steps, with true parameters on the
#    ellipsoid's boundary.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

from robust_drake.experiments.calafiore import run_ellipsoid_experiment, run_study
from robust_drake.regressor import IMI_P, IMI_THETA0

SHORT = bool(os.environ.get("ROBUST_DRAKE_SHORT"))
N_SAMPLES = [5, 20] if SHORT else [5, 20, 100]

# %% [markdown]
# ## Ellipsoids from 5 samples (the paper) and more

# %%
results = {}
for n in N_SAMPLES:
    out = run_ellipsoid_experiment(n, draws=300 if SHORT else 1000)
    results[n] = out
    c = out["containment"]
    print(f"n_m = {n:4d}: trace(P) = {out['trace']:9.3f}, solve {out['solve_seconds']:.2f} s, "
          f"certificate {c['inside']}/{c['tested']} (max radius {c['max_radius']:.3f}), "
          f"true theta at radius {out['true_theta_radius']:.3f}")
print("published (5 samples, measured data): trace(P) =", np.trace(IMI_P))

# %%
fig, ax = plt.subplots()
names = ["G1z+m2l1^2", "m2s2x", "m2s2y", "G2z", "ss1", "sv1", "ss2", "sv2"]
for k, (n, out) in enumerate(results.items()):
    ax.errorbar(np.arange(8) + 0.15 * k, out["theta0"], yerr=np.sqrt(np.diag(out["P"])), fmt="o", label=f"n_m={n}")
ax.set_xticks(range(8), names, rotation=45)
ax.set_ylabel("theta0 +- sqrt(P_ii)")
ax.legend()
plt.show()

# %% [markdown]
# ## Nominal vs robust control, published ellipsoid (section 5.1) and our own

# %%
study = run_study(n_true=2 if SHORT else 4)
own = results[N_SAMPLES[-1]]
study_own = run_study(own["theta0"], own["P"], n_true=2 if SHORT else 4)
for label, s in (("published", study), (f"own, n_m={N_SAMPLES[-1]}", study_own)):
    for law in ("nominal", "robust"):
        m = s["summary"][law]
        print(f"{label:>14s} {law:8s} peak {np.round(m['peak'], 4)} rms {np.round(m['rms'], 4)} "
              f"settling {np.round(m['settling_time'], 3)} s")

# %%
logs = study["runs"][0]["_logs"]
fig, axes = plt.subplots(1, 2, figsize=(10, 3.5), sharey=True)
for ax, law in zip(axes, ("nominal", "robust")):
    ax.plot(logs[law]["t"], logs[law]["e"])
    ax.set(title=f"{law} control (CI fig. {5 if law == 'nominal' else 6})", xlabel="t [s]")
    ax.legend(["joint 1", "joint 2"], loc="upper right")
axes[0].set_ylabel("tracking error [rad]")
plt.show()
