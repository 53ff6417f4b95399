"""From an identified model to a robust controller checked over the model's confidence set.

The path of ``robust-drake control REPORT.json`` (and ``rd.control``), the same for a user's arm
and for the simulated demo of ``logs-to-control``:

1. the model (:class:`~robust_drake.identification.model.IdentifiedModel`: a repair's report, a
   model file, ``rd.identify``'s result) and its 1 - alpha confidence set E(P, theta0) (CI eq. 10,
   :meth:`IdentifiedModel.confidence_set`);
2. the controller designed from them: CI eq. 15 (``"ci"``: the ellipsoid itself, the sampled-loop
   boundary layer of ``ultimate_bound.sampled_layer``; an identified centre that is no rigid-body
   arm is replaced by the nearest one in the set with the set inflated to keep all of it,
   :func:`recentre_on_rigid_body`) or Spong's SP1 / SP2 (``"sp1"``, ``"sp2"``: JS eqs. 18
   / SP2 with rho = sqrt(lambda_max(P)) / rho_i = sqrt(P_ii), the bounds of ||theta~||_2 and
   |theta~_i| over the set; boundary layer ``spong.default_epsilon``); gains ``spong.default_gains``;
3. the design's nominal run: the controller on the identified arm itself (its rigid body, friction
   and effects: ``ClosedLoopConfig.plant_model``), the identified friction and effects compensated
   (``ClosedLoopConfig.model``: feedforward, stateful effects as blocks), exact state, no
   saturation (the theory's assumptions), the ``sine`` reference for ``track_duration`` s at the
   robot's rate;
4. Monte Carlo over the set: half the draws on its boundary, half inside, each a physically valid
   arm (``uncertainty.plant_draws``) with the identified friction and effects; each run's largest
   error per joint after ``transient`` is compared with that plant's per-joint ultimate bound
   (``ultimate_bound.per_joint_bound`` with rho epsilon: epsilon for CI, rho epsilon for SP1,
   sum rho_i epsilon_i for SP2; M(q) on ``ultimate_bound.bound_region``). The verdict says whether
   every draw stayed within its bound.

The design (controller, gains, theta0, the set, epsilon, rate) and the nominal run's
:class:`~robust_drake.diagram.ClosedLoopConfig` are written as YAML (``design``), which
``robust-drake simulate --design FILE`` reloads and reruns (the same floats: the run is repeated
bit for bit). With ``friction=False`` the plants are the drawn rigid bodies alone, without
friction, effects or compensation (``logs-to-control``'s simulated arm: the theorem's
frictionless plant).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from robust_drake.errors import RobustDrakeError

#: ``--controller`` name -> registry controller
CONTROLLERS = {"ci": "calafiore", "sp1": "sp1", "sp2": "sp2"}


@dataclass
class ControlConfig:
    """Options of :func:`run_control` (times [s], rate [Hz])."""

    controller: str = "ci"
    alpha: float = 0.01  # 1 - alpha confidence set
    draws: int = 8
    boundary_share: float = 0.5
    track_duration: float = 2.0
    transient: float = 1.0
    rate: float | None = None  # None: the robot description's
    seed: int = 0
    friction: bool = True  # the identified friction and effects in every plant, compensated
    design: str | None = None  # path of the design YAML to write (None: not written)

    def check(self) -> None:
        if self.controller not in CONTROLLERS:
            raise RobustDrakeError(f"controller must be one of {', '.join(CONTROLLERS)} (got {self.controller!r})")
        if not 0.0 < self.alpha < 1.0:
            raise RobustDrakeError(f"alpha must lie in (0, 1) (got {self.alpha})")
        if int(self.draws) < 1:
            raise RobustDrakeError(f"draws must be at least 1 (got {self.draws})")
        if not 0.0 <= self.boundary_share <= 1.0:
            raise RobustDrakeError(f"boundary_share must lie in [0, 1] (got {self.boundary_share})")
        if not (self.track_duration > 0 and 0.0 <= self.transient < self.track_duration):
            raise RobustDrakeError("track_duration must be > 0 and transient in [0, track_duration)")
        if self.rate is not None and not self.rate > 0:
            raise RobustDrakeError(f"rate must be a positive number of Hz (got {self.rate})")


@dataclass
class _DesignContext:
    """What ``logs_to_control.design_eq15`` reads from its config."""

    robot: str
    rate: float
    track_duration: float


def design_eq15(cfg, reg, theta0, P):
    """Eq. 15's parameters from the set: the ellipsoid and the sampled-loop boundary layer
    (``ultimate_bound.sampled_layer``, with M(q) of theta0 along the loop's reference); returns
    (controller params, K, Lambda, layer info, reference positions (200, n))."""
    from robust_drake.experiments.ultimate_bound import mass_matrices, sampled_layer
    from robust_drake.models import ArmSpec
    from robust_drake.trajectories import make_reference
    from robust_drake.uncertainty.ellipsoid import Ellipsoid

    ref = make_reference(ArmSpec(cfg.robot, cfg.robot, reg.n, (), True, None), "sine")
    t = np.linspace(0.0, cfg.track_duration, 200)
    q, qd, qdd = (np.asarray(x, float).reshape(-1, reg.n) for x in ref(t))
    centre, P_ctrl, recentred = theta0, P, None
    Ms = mass_matrices(reg, theta0, q)
    if np.linalg.eigvalsh(Ms)[:, 0].min() <= 0:
        centre, P_ctrl, recentred = recentre_on_rigid_body(reg, theta0, P)
        Ms = mass_matrices(reg, centre, q)
        if np.linalg.eigvalsh(Ms)[:, 0].min() <= 0:  # pragma: no cover - a certified rigid body has M > 0
            raise RobustDrakeError(f"{cfg.robot}: M(q) of the recentred nominal model is not positive definite")
    ell = Ellipsoid(centre, P_ctrl)
    ctrl = _closed_loop_controller(cfg, {"ellipsoid": ell})
    K, Lam = np.asarray(ctrl.K, float), np.asarray(ctrl.Lambda, float)
    eps = sampled_layer(reg.evaluate(q, qd, qdd), ell.E, Ms, K, 1.0 / cfg.rate)
    info = {"epsilon": eps, "previous_rule_epsilon": float(ctrl.epsilon),
            "rule": "sampled-loop margin epsilon = g_max h / (beta - h k_max) (ultimate_bound.sampled_layer)",
            "recentred": recentred}
    return {"ellipsoid": ell, "epsilon": eps}, K, Lam, info, q


def recentre_on_rigid_body(reg, theta0, P):
    """(theta_c, P_c, info) for a set whose centre theta0 is no rigid-body arm (its M(q) is not
    positive definite on the reference, seen on the Panda's light wrist): theta_c = the nearest
    (P^-1 metric) physically valid point of E(P, theta0) (``plant_draws.NearestPhysical``, certified),
    at radius r_c < 1, and P_c = (1 + r_c)^2 P. Sound: for every theta in E(P, theta0),
    ||theta - theta_c||_{P^-1} <= ||theta - theta0||_{P^-1} + ||theta0 - theta_c||_{P^-1} <= 1 + r_c,
    so E(P, theta0) lies in E(P_c, theta_c), the set eq. 15 is designed for; the price is the
    factor (1 + r_c) on the set's size."""
    from robust_drake.uncertainty.plant_draws import NearestPhysical
    from robust_drake.uncertainty.confidence import mahalanobis_radius

    pi = NearestPhysical(reg, reg.standard_parameters(), theta0, P)(theta0)
    if pi is None:
        raise RobustDrakeError("the identified centre is no rigid-body arm (M(q) not positive definite on "
                               "the reference) and no physically valid arm was found inside the set")
    theta_c = np.asarray(reg.K, float) @ pi
    r_c = mahalanobis_radius(theta0, P, theta_c)
    return theta_c, (1.0 + r_c) ** 2 * np.asarray(P, float), {
        "radius": r_c, "inflation": (1.0 + r_c) ** 2,
        "why": "M(q) of the identified centre is not positive definite on the reference: eq. 15 uses the "
               "nearest rigid-body arm of the set and the set inflated to keep all of it"}


def _closed_loop_controller(cfg, params):
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    c = ClosedLoopConfig(robot=cfg.robot, controller="calafiore", controller_params=dict(params),
                         trajectory="sine", rate=cfg.rate, duration=cfg.track_duration, observer="exact")
    return build_closed_loop(c).controller


def _plant_arm(model, friction: bool):
    """The model the plants are made of: as identified, or without friction and effects."""
    if friction:
        return model
    n = model.n
    return dataclasses.replace(model, coulomb=np.zeros(n), viscous=np.zeros(n), effects=[])


def design(model, cfg: ControlConfig, reg, rate: float) -> dict:
    """The controller of ``cfg.controller`` from the model and its set: ``params`` (its
    controller_params: CI theta0, P, epsilon, K, Lambda; SP1/SP2 the model (JSON) and alpha,
    epsilon, K, Lambda), ``rho_epsilon`` (the bound's rho
    epsilon), ``K``, ``Lambda``, ``epsilon_rule``, the set (``theta0``, ``P``), ``q_ref``."""
    from robust_drake.systems.controllers.spong import closed_form_for

    ell = model.confidence_set(cfg.alpha)
    theta0, P = ell.theta0, ell.P
    dctx = _DesignContext(str(model.robot), rate, cfg.track_duration)
    if cfg.controller == "ci":
        prm, K, Lam, layer, q_ref = design_eq15(dctx, reg, theta0, P)
        e = prm["ellipsoid"]
        params = {"theta0": e.theta0.tolist(), "P": e.P.tolist(), "epsilon": float(prm["epsilon"])}
        rho_eps, rule = float(prm["epsilon"]), layer
    else:
        if closed_form_for(model.robot) is not None:
            raise RobustDrakeError(f"{model.robot}: SP1/SP2 use the robot's closed-form design, not the identified "
                                   "base parameters; use --controller ci")
        ctrl_model = _plant_arm(model, cfg.friction)  # friction=False: nothing to compensate
        ctrl = _controller(dctx, CONTROLLERS[cfg.controller], {"model": ctrl_model, "alpha": cfg.alpha})
        K, Lam = np.asarray(ctrl.K, float), np.asarray(ctrl.Lambda, float)
        rho, eps = ctrl.rho, ctrl.epsilon
        # reloaded through model= (theta0 and rho from the same set, the model's compensation)
        params = {"model": ctrl_model.to_json(), "alpha": cfg.alpha, "epsilon": eps}
        rho_eps = float(rho * eps) if np.ndim(rho) == 0 else float(np.sum(np.asarray(rho) * np.asarray(eps)))
        rule = dict(ctrl.uncertainty.get("epsilon_rule") or {})
        q_ref = _reference_q(dctx, reg.n)
    params.update(K=K.tolist(), Lambda=Lam.tolist())
    return {"params": params, "rho_epsilon": rho_eps, "K": K, "Lambda": Lam, "epsilon_rule": rule,
            "theta0": theta0, "P": P, "q_ref": q_ref}


def _controller(dctx, name: str, params: dict):
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    c = ClosedLoopConfig(robot=dctx.robot, controller=name, controller_params=dict(params), trajectory="sine",
                         rate=dctx.rate, duration=dctx.track_duration, observer="exact")
    return build_closed_loop(c).controller


def _reference_q(dctx, n: int, samples: int = 200) -> np.ndarray:
    from robust_drake.models import ArmSpec
    from robust_drake.trajectories import make_reference

    ref = make_reference(ArmSpec(dctx.robot, dctx.robot, n, (), True, None), "sine")
    return np.asarray(ref(np.linspace(0.0, dctx.track_duration, samples))[0], float).reshape(-1, n)


def nominal_config(model, cfg: ControlConfig, params: dict, rate: float):
    """The design's nominal loop: the controller on the identified arm (module docstring)."""
    from robust_drake.diagram import ClosedLoopConfig

    arm = _plant_arm(model, cfg.friction)
    return ClosedLoopConfig(robot=str(model.robot), controller=CONTROLLERS[cfg.controller],
                            controller_params=dict(params), trajectory="sine", rate=rate,
                            duration=cfg.track_duration, observer="exact", encoder_resolution=None,
                            torque_limit=None, plant_model=arm,
                            model=model if cfg.friction and "model" not in params else None)


def _draw_config(nominal, arm, draw):
    """``nominal`` with the plant = the drawn rigid body (``draw.setup``) + the arm's friction and
    effects (plant-modifying ones applied after the drawn inertias)."""
    hooks = arm.closed_loop_hooks(plant=True, controller=False, rigid_body=False)
    return dataclasses.replace(nominal, plant_model=None, plant_friction=hooks["plant_friction"],
                               effects=hooks["effects"], plant_setup=[draw.setup] + hooks["plant_setup"])


def _run_draw(nominal, arm, d, des, region, plant, ell, transient, previous_eps=None) -> dict:
    """One drawn plant under the design: its per-joint bound and its errors after the transient."""
    from robust_drake.diagram import build_closed_loop
    from robust_drake.experiments.ultimate_bound import mass_bounds, norm_bound, per_joint_bound

    c = _draw_config(nominal, arm, d)
    res = build_closed_loop(c).simulate()
    ctx = plant.CreateDefaultContext()
    for setup in c.plant_setup:
        setup(plant, ctx)
    mb = mass_bounds(plant, ctx, region, des["K"])
    bj = per_joint_bound(des["rho_epsilon"], mb, des["Lambda"])
    after = res.t >= transient
    ej = np.full(len(bj), np.inf) if (res.diverged or not after.any()) else np.abs(res.q - res.q_d)[after].max(axis=0)
    out = {"kind": d.kind, "radius": float(ell.radius(d.theta)), "theta": d.theta.tolist(), "projected": bool(d.projected),
           "bound": max(bj), "max_error": float(ej.max()), "ratio": float(max(bj) / ej.max()),
           "bound_per_joint": bj, "max_error_per_joint": ej.tolist(),
           "within": bool(np.all(ej <= np.asarray(bj))), "diverged": bool(res.diverged),
           "epsilon": des["params"]["epsilon"], "norm_bound": norm_bound(des["rho_epsilon"], mb, des["Lambda"]),
           "kappa": mb.kappa, "k_min_over_m_max": mb.k_min / mb.m_max,
           "sqrt_m_ratio": float(np.sqrt(mb.m_max / mb.m_min)), "minv": list(mb.minv)}
    if previous_eps is not None:
        out["previous_bound"] = norm_bound(previous_eps, mb, des["Lambda"])
    return out


def verdict(draws, region_info, hint: str = "a smaller confidence set (more or richer logs) or another "
            "controller may") -> dict:
    """``guaranteed`` (every drawn plant's loop ran to the end and stayed within its per-joint bound,
    and, where M(q) was bounded over the reference tube, every bound lies inside that tube) and a
    one-line ``verdict`` saying which condition failed and what to change (``hint``)."""
    diverged = [i for i, d in enumerate(draws) if d["diverged"] or not np.isfinite(d["max_error"])]
    outside = [i for i, d in enumerate(draws) if not d["within"] and i not in diverged]
    reasons = []
    if diverged:
        reasons.append(f"the loop of draw(s) {diverged} diverged")
    if outside:
        reasons.append(f"draw(s) {outside} left their bound")
    if region_info.get("kind") == "tube" and not region_info.get("consistent"):
        reasons.append(f"bounds up to {max(d['bound'] for d in draws):.3g} rad exceed the +-{region_info['delta']} "
                       "rad tube over which M(q) was bounded")
    if not reasons:
        return {"guaranteed": True, "verdict": "every drawn plant stayed within its bound"}
    return {"guaranteed": False, "verdict": "not shown: " + "; ".join(reasons) + f" ({hint})"}


def run_control(model, cfg: ControlConfig | None = None, progress=None, desc: str = "control") -> dict:
    """The whole path (module docstring); a JSON-able dict with the keys ``logs-to-control``
    prints (``uncertainty``, ``rho``, ``bound``, ``max_error``, ``draws``, ``rejected``,
    ``region``, ``epsilon_rule``, ``K``, ``Lambda``, ``pd_max_error``, ``guaranteed``,
    ``verdict``) plus ``controller``, ``design``, ``nominal`` and ``design_file``. With ``progress``
    None a bar (terminal, notebook) or a log line every ~10 % labelled ``desc`` follows the steps."""
    from robust_drake.diagram import build_closed_loop
    from robust_drake.uncertainty.plant_draws import draw_plants
    from robust_drake.experiments.ultimate_bound import bound_region
    from robust_drake.log import progress_bar, progress_callback
    from robust_drake.loop_defaults import robot_rate
    from robust_drake.identification.model import as_identified_model
    from robust_drake.models import make_plant
    from robust_drake.regressor import InverseDynamicsRegressor

    cfg = cfg or ControlConfig()
    cfg.check()
    log = progress_callback(progress)
    # steps: design + nominal run, the set's draws, each draw's run, PD
    bar = progress_bar(int(cfg.draws) + 3, desc, unit="steps", enabled=progress is None)
    m = as_identified_model(model)
    reg = InverseDynamicsRegressor.from_robot(m.robot)
    if list(reg.base_names) != list(m.base_names):
        raise RobustDrakeError(f"the model's base parameters are not those of {m.robot!r}'s regressor")
    rate = float(cfg.rate) if cfg.rate is not None else robot_rate(m.robot)
    des = design(m, cfg, reg, rate)
    nominal = nominal_config(m, cfg, des["params"], rate)
    log(f"{cfg.controller} designed from the {1 - cfg.alpha:g} set of {m.robot} ({m.estimator}); nominal run ...")
    loop = build_closed_loop(nominal)
    nom = loop.simulate()
    bar.update(1)
    plant = make_plant(m.robot)
    region, region_info = bound_region(plant, des["q_ref"], np.random.default_rng(cfg.seed + 1))
    arm = _plant_arm(m, cfg.friction)
    from robust_drake.uncertainty.ellipsoid import Ellipsoid

    ell = Ellipsoid(des["theta0"], des["P"])
    plants, rejected = draw_plants(reg, des["theta0"], des["P"], int(cfg.draws), np.random.default_rng(cfg.seed),
                                   cfg.boundary_share)
    prev = des["epsilon_rule"].get("previous_rule_epsilon")
    bar.update(1)
    draws = []
    for i, d in enumerate(plants):
        log(f"draw {i + 1}/{len(plants)} ({d.kind})")
        draws.append(_run_draw(nominal, arm, d, des, region, plant, ell, cfg.transient, prev))
        bar.update(1)
    if region_info["kind"] == "tube":
        region_info["consistent"] = bool(all(max(d["bound_per_joint"]) <= region_info["delta"] for d in draws))
    pd = build_closed_loop(dataclasses.replace(nominal, controller="pd", model=None, controller_params={
        "K": des["params"]["K"], "Lambda": des["params"]["Lambda"]})).simulate()
    pd_err = float(np.max(np.abs(pd.q - pd.q_d)[pd.t >= cfg.transient]))
    bar.update(1)
    bar.close()
    out = _result(m, cfg, des, rate, nominal, loop, nom, draws, rejected, region_info, pd_err)
    if cfg.design:
        out["design_file"] = write_design(out, nominal, cfg.design)
    return out


def _result(m, cfg, des, rate, nominal, loop, nom, draws, rejected, region_info, pd_err) -> dict:
    P = des["P"]
    after = nom.t >= cfg.transient
    unc = {"kind": "ellipsoid", "source": f"{1 - cfg.alpha:g} confidence set of the identified base parameters "
           f"({m.estimator}, {covariance_kind(m)} covariance)", "parameters": list(m.base_names),
           "theta0": np.asarray(des["theta0"], float).tolist(), "P": np.asarray(P, float).tolist()}
    shown = {k: v for k, v in des["params"].items() if k != "model"}  # the model is in closed_loop
    ctrl = loop.controller
    if "model" in des["params"]:  # SP1/SP2: what the factory took from the model
        shown.update(theta0=np.asarray(ctrl.theta0, float).tolist(), rho=ctrl.rho)
    design_rec = {"controller": cfg.controller, "registry_controller": CONTROLLERS[cfg.controller],
                  "robot": str(m.robot), "rate": rate, "alpha": cfg.alpha, **shown,
                  "rho_epsilon": des["rho_epsilon"], "set": unc, "friction_compensated": bool(cfg.friction),
                  "not_compensated": dict(getattr(loop, "not_compensated", {}) or
                                          getattr(loop.controller, "not_compensated", {}) or {})}
    return {"robot": str(m.robot), "controller": cfg.controller, "alpha": cfg.alpha,
            "samples": int((m.data or {}).get("samples", 0) or 0), "estimator": m.estimator,
            "uncertainty": unc, "rho": float(np.sqrt(np.linalg.eigvalsh(P)[-1])),
            "bound": max(d["bound"] for d in draws), "max_error": max(d["max_error"] for d in draws),
            "draws": draws, "rejected": rejected, "region": region_info, "epsilon_rule": des["epsilon_rule"],
            "K": des["K"].tolist(), "Lambda": des["Lambda"].tolist(), "pd_max_error": pd_err,
            "design": design_rec,
            "nominal": {"metrics": dict(nom.metrics), "diverged": bool(nom.diverged),
                        "max_error_per_joint": (np.abs(nom.q - nom.q_d)[after].max(axis=0).tolist()
                                                if after.any() and not nom.diverged else None),
                        "samples": int(len(nom.t))},
            **verdict(draws, region_info)}


def covariance_kind(model) -> str:
    """How the identified model's covariance was estimated (``model.data["covariance"]["kind"]``;
    least squares without that entry: homoscedastic, inflated by N / N_eff)."""
    kind = ((model.data or {}).get("covariance") or {}).get("kind")
    return str(kind) if kind else "N/N_eff-inflated homoscedastic"


def write_design(out: dict, nominal, path) -> str:
    """The design YAML: ``design`` (controller, gains, theta0, the set, epsilon, rate, ...),
    ``closed_loop`` (the nominal run's :class:`ClosedLoopConfig`, which ``simulate --design``
    reloads), ``nominal`` (that run's metrics) and ``verdict``."""
    import os

    import yaml

    from robust_drake.diagram import _plain_data

    doc = {"format": "robust_drake.design", "version": 1, "design": out["design"],
           "closed_loop": nominal.resolved().to_dict(), "nominal": out["nominal"],
           "verdict": {"guaranteed": out["guaranteed"], "verdict": out["verdict"], "bound": out["bound"],
                       "max_error": out["max_error"]}}
    text = yaml.safe_dump(_plain_data(doc), sort_keys=False, width=120)
    try:
        os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
        with open(path, "w") as fh:
            fh.write(text)
    except OSError as exc:
        raise RobustDrakeError(f"cannot write the design to {path}: {exc.strerror or exc}") from None
    return os.fspath(path)
