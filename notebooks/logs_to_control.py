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
# 1. A simulated identification experiment on an arm with a known truth (the Siciliano vertical
#    2-link arm): 5 s of a PD-tracked Fourier excitation, torque noise of 2 % of the largest
#    gravity torque.
# 2. The repair pipeline identifies the base parameters with their covariance (an `IdentifiedModel`).
# 3. Its 99 % confidence ellipsoid E(P, theta0) (Calafiore & Indri eq. 10) is the uncertainty set.
# 4. Calafiore & Indri's eq. 15 controller is designed from (theta0, P).
# 5. Monte Carlo: plants drawn across the set (half on its boundary, half inside, each a physically
#    valid arm) are tracked; each one's largest error after the transient must stay below the
#    ultimate bound the theory predicts for it.
#
# The same loop is `robust-drake logs-to-control --robot siciliano_2link`.

# %%
import os
import tempfile

import matplotlib.pyplot as plt
import numpy as np

from robust_drake.diagram import ClosedLoopConfig, simulate
from robust_drake.experiments.logs_to_control import (LogsToControlConfig, mass_extremes, identify,
                                                      ultimate_error_bound)
from robust_drake.experiments.plant_draws import draw_plants
from robust_drake.regressor import InverseDynamicsRegressor
from robust_drake.uncertainty.confidence import confidence_ellipsoid, mahalanobis_radius
from robust_drake.uncertainty.ellipsoid import Ellipsoid

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
cfg = LogsToControlConfig(robot="siciliano_2link", draws=4 if SHORT else 10,
                          track_duration=1.5 if SHORT else 2.0, transient=1.0)

# %% [markdown]
# ## Logs -> identified model -> confidence set

# %%
with tempfile.TemporaryDirectory() as tmp:
    model = identify(cfg, tmp)  # writes the simulated log, runs the repair (no effects)
theta0, P = confidence_ellipsoid(model, cfg.alpha)
reg = InverseDynamicsRegressor.from_robot(cfg.robot)
truth = reg.base_parameters()
print(f"{model.data['samples']} samples, estimator {model.estimator}")
for name, est, t, half in zip(model.base_names, theta0, truth, np.sqrt(np.diag(P))):
    print(f"  {name:70s} {est:10.4g} +- {half:9.3g}   truth {t:10.4g}")
print(f"truth at Mahalanobis radius {mahalanobis_radius(theta0, P, truth):.2f} (inside: <= 1)")

# %% [markdown]
# ## Robust controller and Monte Carlo over the set

# %%
draws, rejected = draw_plants(reg, theta0, P, cfg.draws, np.random.default_rng(cfg.seed))
q_grid = [np.array([0.0, q2]) for q2 in np.linspace(-np.pi, np.pi, 73)]
ell = Ellipsoid(theta0, P)
runs = []
for d in draws:
    res = simulate(ClosedLoopConfig(robot=cfg.robot, controller="calafiore", controller_params={"ellipsoid": ell},
                                    trajectory="sine", rate=cfg.rate, duration=cfg.track_duration, observer="exact",
                                    plant_friction=None, encoder_resolution=None, torque_limit=None,
                                    plant_setup=[d.setup]))
    m_min, m_max = mass_extremes(cfg.robot, d.setup, q_grid)
    runs.append((d, res, m_min, m_max))
pd = simulate(ClosedLoopConfig(robot=cfg.robot, controller="pd", trajectory="sine", rate=cfg.rate,
                               duration=cfg.track_duration, observer="exact", plant_friction=None,
                               encoder_resolution=None, torque_limit=None))
print(f"{len(draws)} plants ({rejected} physically invalid draws redrawn)")

# %% [markdown]
# The ultimate bound needs the controller's K, Lambda and boundary layer epsilon: build the
# controller once (it is the same for every plant) and evaluate the bound per plant.

# %%
from robust_drake.diagram import build_closed_loop

ctrl = build_closed_loop(ClosedLoopConfig(robot=cfg.robot, controller="calafiore", controller_params={"ellipsoid": ell},
                                          trajectory="sine", rate=cfg.rate, duration=cfg.track_duration,
                                          observer="exact")).controller
rows = []
for d, res, m_min, m_max in runs:
    bound = ultimate_error_bound(ctrl.K, ctrl.Lambda, ctrl.epsilon, m_min, m_max)
    err = float(np.abs(res.q - res.q_d)[res.t >= cfg.transient].max())
    rows.append((d.kind, d.radius, err, bound))
    print(f"{d.kind:8s} radius {d.radius:.3f}: max |e| {err:.3g} rad  bound {bound:.3g} rad  "
          f"{'within' if err <= bound else 'OUTSIDE'}")
pd_err = float(np.abs(pd.q - pd.q_d)[pd.t >= cfg.transient].max())
print(f"PD with the same K, Lambda on the URDF arm: {pd_err:.3g} rad")

# %%
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.5))
for d, res, _, _ in runs:
    ax0.semilogy(res.t, np.abs(res.q - res.q_d).max(axis=1), lw=0.8,
                 color="C0" if d.kind == "boundary" else "C2")
ax0.semilogy(pd.t, np.abs(pd.q - pd.q_d).max(axis=1), color="C3", lw=0.8, label="PD (URDF arm)")
ax0.axhline(max(r[3] for r in rows), color="k", ls="--", lw=1, label="largest bound")
ax0.axvline(cfg.transient, color="grey", ls=":", lw=1)
ax0.set_xlabel("t [s]")
ax0.set_ylabel("max_j |q~_j| [rad]")
ax0.legend(fontsize=8)
ax0.set_title("CI eq. 15 on plants drawn across the set\n(blue: boundary, green: inside)", fontsize=9)
x = np.arange(len(rows))
ax1.bar(x - 0.2, [r[2] for r in rows], 0.4, label="max |e| after the transient")
ax1.bar(x + 0.2, [r[3] for r in rows], 0.4, label="predicted ultimate bound")
ax1.set_yscale("log")
ax1.set_ylim(top=5 * max(r[3] for r in rows))  # room for the legend
ax1.set_xticks(x, [f"{r[0][0]} {r[1]:.2f}" for r in rows], fontsize=7)
ax1.set_xlabel("draw (b = boundary, i = inside; Mahalanobis radius)")
ax1.set_ylabel("[rad]")
ax1.legend(fontsize=8)
fig.tight_layout()
plt.show()
