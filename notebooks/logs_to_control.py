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
# # From logs to a guaranteed controller
#
# 1. A simulated identification experiment on an arm with a known truth (the PUMA 560's first
#    three joints, Armstrong, Khatib & Burdick's inertias, Corke & Armstrong-Helouvry's friction):
#    5 s of a PD-tracked Fourier excitation within its torque limits, torque noise of 2 % of the
#    largest gravity torque.
# 2. The repair pipeline identifies the 16 base parameters with their covariance (an `IdentifiedModel`).
# 3. Its 99 % confidence ellipsoid E(P, theta0) (Calafiore & Indri eq. 10) is the uncertainty set.
# 4. Calafiore & Indri's eq. 15 controller is designed from (theta0, P), with the smallest boundary
#    layer the 1 kHz loop tolerates.
# 5. Monte Carlo: plants drawn across the set (half aimed at its boundary, half inside, each a
#    physically valid arm) are tracked; each joint's largest error after the transient must stay
#    below that joint's ultimate bound, computed for that plant.
#
# The same loop is `robust-drake logs-to-control --robot puma560_3link`.

# %%
# %matplotlib inline
import os

import matplotlib.pyplot as plt
import numpy as np

from robust_drake.experiments.logs_to_control import (LogsToControlConfig, track_plant, design_eq15,
                                                      identified_set)
from robust_drake.uncertainty.plant_draws import draw_plants
from robust_drake.experiments.ultimate_bound import bound_region, mass_bounds, per_joint_bound
import robust_drake as rd

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
cfg = LogsToControlConfig(robot="puma560_3link", draws=3 if SHORT else 8,
                          track_duration=1.5 if SHORT else 2.0, transient=1.0)

# %% [markdown]
# ## Logs -> identified model -> confidence set

# %%
model, theta0, P, reg, truth, truth_r = identified_set(cfg, None)  # simulated log + repair (no effects)
print(f"{model.data['samples']} samples, estimator {model.estimator}")
for name, est, t, half in zip(model.base_names, theta0, truth, np.sqrt(np.diag(P))):
    print(f"  {name[:60]:60s} {est:10.4g} +- {half:9.3g}   truth {t:10.4g}")
print(f"truth at Mahalanobis radius {truth_r:.2f} (inside: <= 1)")

# %% [markdown]
# ## Robust controller, its guaranteed bound, and the Monte Carlo over the set
#
# Per joint j, once the error is small: |e_j| <= sqrt(max (M^-1)_jj epsilon / (4 kappa)) / Lambda_j,
# kappa = min lambda_min(M^-1 K), M(q) of the drawn plant over a global grid of the joints that
# change M (here shoulder and elbow; `experiments.ultimate_bound`).

# %%
params, K, Lam, layer, q_ref = design_eq15(cfg, reg, theta0, P)
print(f"boundary layer {layer['epsilon']:.3g} (previous rule {layer['previous_rule_epsilon']:.3g})")
plant = rd.make_plant(cfg.robot)
region, info = bound_region(plant, q_ref, np.random.default_rng(1))
draws, rejected = draw_plants(reg, theta0, P, cfg.draws, np.random.default_rng(cfg.seed))
rows = []
for d in draws:
    _, res = track_plant(cfg, "calafiore", params, d.setup)
    ctx = plant.CreateDefaultContext()
    d.setup(plant, ctx)
    bound = np.array(per_joint_bound(params["epsilon"], mass_bounds(plant, ctx, region, K), Lam))
    err = np.abs(res.q - res.q_d)[res.t >= cfg.transient].max(axis=0)
    rows.append((d, res, err, bound))
    print(f"{d.kind:8s} radius {d.radius:.3f}{' (nearest valid)' if d.projected else ''}: "
          f"max |e_j| {np.round(err, 6)}  bound {np.round(bound, 6)}  "
          f"{'within' if np.all(err <= bound) else 'OUTSIDE'}")
_, pd = track_plant(cfg, "pd", {"K": K.tolist(), "Lambda": Lam.tolist()}, lambda plant, ctx: None)
pd_err = float(np.abs(pd.q - pd.q_d)[pd.t >= cfg.transient].max())
print(f"{rejected} draws no rigid body realises redrawn; PD with the same K, Lambda on the URDF arm: {pd_err:.3g} rad")

# %%
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.5))
for d, res, _, _ in rows:
    ax0.semilogy(res.t, np.abs(res.q - res.q_d).max(axis=1), lw=0.8,
                 color="C0" if d.kind == "boundary" else "C2")
ax0.semilogy(pd.t, np.abs(pd.q - pd.q_d).max(axis=1), color="C3", lw=0.8, label="PD (URDF arm)")
ax0.axhline(max(r[3].max() for r in rows), color="k", ls="--", lw=1, label="largest bound")
ax0.axvline(cfg.transient, color="grey", ls=":", lw=1)
ax0.set_xlabel("t [s]")
ax0.set_ylabel("max_j |q~_j| [rad]")
ax0.legend(fontsize=9)
ax0.set_title("CI eq. 15 on plants drawn across the set\n(blue: aimed at the boundary, green: inside)", fontsize=9)
n = len(K)
for j in range(n):
    x = np.arange(len(rows)) * (n + 1) + j
    ax1.bar(x, [r[2][j] for r in rows], 0.8, color=f"C{j}", label=f"joint {j}: max |e|")
    ax1.scatter(x, [r[3][j] for r in rows], color="k", marker="_", s=120, zorder=3)
ax1.set_yscale("log")
ax1.set_xticks(np.arange(len(rows)) * (n + 1) + 1, [f"{r[0].kind[0]} {r[0].radius:.2f}" for r in rows], fontsize=8.5)
ax1.set_xlabel("draw (b = boundary, i = inside; Mahalanobis radius); black: that joint's bound")
ax1.set_ylabel("[rad]")
ax1.legend(fontsize=8.5)
fig.tight_layout()
plt.show()
