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
# # Identify your arm: URDF -> excitation -> experiment -> repair -> URDF -> control
#
# A new arm comes with a URDF and nothing else.  This notebook runs the whole path on the DFKI
# double pendulum C.1 (`robots/dfki_double_pendulum_c1.urdf`, replace it by your file):
#
# 1. **excite**: a periodic, band-limited Fourier motion that maximises log det of the information
#    of the base parameters, friction and a cogging torque, inside the joint position, velocity and
#    torque limits, at rest at the start pose at both ends (`rd.excite`, `robust-drake excite`);
# 2. **experiment**: here a simulated one (the arm with a cogging torque on the elbow that the URDF
#    does not know, friction, torque noise); on hardware, track the written CSV and log `t, q, tau`;
# 3. **repair**: identify, find the missing effect, report before/after (`rd.repair`);
# 4. **export**: the physically consistent identified arm as a URDF + the effects in a sidecar YAML;
# 5. **control**: Calafiore & Indri's eq. 15 designed from the identified model and its confidence
#    set, checked on arms drawn across that set (`rd.control`, `robust-drake control`), then SP1
#    (Jaritz & Spong) with the identified model as its nominal parameters and uncertainty set.

# %%
import os
import tempfile

# %matplotlib inline
import robust_drake as rd

SHORT = os.environ.get("ROBUST_DRAKE_SHORT") == "1"
out = os.environ.get("ROBUST_DRAKE_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="identify_")
robot, duration = "dfki_double_pendulum_c1", 6.0 if SHORT else 10.0

# %% [markdown]
# ## 1. The excitation

# %%
design = rd.excite(robot, duration=duration, harmonics=4 if SHORT else None, effects=("position_dependent",))
design.to_csv(os.path.join(out, "excitation.csv"))
rep = design.report
print(f"log det {rep['log_det']:.1f} vs default {rep['default']['log_det']:.1f}; predicted std smaller by a "
      f"median {rep['median_std_ratio']:.2f}x; torque/limit {[round(x, 2) for x in rep['margins']['torque']['fraction_of_limit']]}")
design.figure()

# %% [markdown]
# ## 2. The experiment (simulated: a 0.06 N m cogging torque, 4 per revolution, on the elbow)

# %%
truth = [("position_dependent", 1, {"amplitude": 0.06, "phase": 0.5, "harmonic": 4})]
kw = dict(robot=robot, effects=truth, duration=duration, coulomb=(0.02, 0.01))  # 5 mN m torque noise
fit, val = os.path.join(out, "fit.csv"), os.path.join(out, "validate.csv")
_ = rd.simulate_experiment(**kw, out_csv=fit, reference=design.trajectory)
_ = rd.simulate_experiment(**kw, out_csv=val, seed=1)  # another motion: the built-in excitation

# %% [markdown]
# ## 3. Repair

# %%
report = rd.repair([fit], robot=robot, validate=[val], out=os.path.join(out, "repair"), overwrite=True,
                   plots=False, effects=["position_dependent", "stribeck", "torque_offset"], replay=not SHORT)
print(f"{report['verdict']}: effects {[e['label'] for e in report['effects']]}; validation RMS "
      f"{[round(x, 3) for x in report['baseline']['rms_validate']]} -> {[round(x, 3) for x in report['final']['rms_validate']]} N m")
rd.repair_figure(report)

# %% [markdown]
# ## 4. Export: URDF (consistent inertials, friction) + sidecar (the cogging)

# %%
model = report.model
files = model.to_urdf(os.path.join(out, "c1_identified.urdf"))
back = rd.IdentifiedModel.load(files["urdf"])
print(files["urdf"], "| sidecar effects:", files["effects_in_sidecar"], "| notes:", files["notes"])
print("round trip:", [e.kind for e in back.effects], back.base_names[:3], "...")

# %% [markdown]
# ## 5. Control: CI eq. 15 from the identified model and its set, then SP1 with the model
#
# Control takes the repair's model (`report.model`, or `report.json`): it carries the confidence
# set; the URDF export is for other tools and keeps the bodies and effects, not the covariance.

# %%
ctl = rd.control(model, "ci", draws=2 if SHORT else 8, track_duration=1.5 if SHORT else 2.0)
print(ctl["verdict"], "| bound per joint [rad]:", ctl["bound"], "| largest error:", ctl["max_error"])
res = rd.simulate(robot=robot, controller="sp1", model=model, plant_model=model, trajectory="sine",
                  duration=1.0 if SHORT else 3.0)
print("SP1 with the identified theta0 and set:", {k: round(v, 5) for k, v in res.metrics.items()})
res.plot()
