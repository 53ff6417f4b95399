"""Optimal excitation for identification: a periodic Fourier motion that maximises log det F.

What is optimised.  The coefficients x of a Fourier series per joint
(:mod:`robust_drake.excitation.fourier`, Swevers, Ganseman et al. 1997) maximise

    J(x) = log det F(x),   F = sum_k A_k^T A_k   (D-optimality)

over one period, A the columns of the base parameters, Coulomb and viscous friction and any
``--for-effects`` kinds (:mod:`robust_drake.excitation.information`).  Why log det and not the
condition number of Gautier & Khalil 1992 (which FloBaRoID minimises, and which is reported):
det F^-1 is the volume of the parameters' confidence ellipsoid, so J is the quantity the
repair's confidence set (``uncertainty.confidence``) depends on; it is invariant to the units and
the choice of base parameters (a reparameterisation theta' = T theta adds log det T^2, a
constant), while the condition number changes with the column scaling (kg vs kg m^2) and counts
only the two extreme directions; and it is smooth where cond(A) = s_max / s_min is not (its
gradient jumps when singular values cross), which a gradient-based solver needs.

Constraints (everything the experiment must respect), posed with Drake's ``MathematicalProgram``
and solved by SNOPT (this pydrake wheel has SNOPT, IPOPT and NLopt; SNOPT's sparse SQP handles the
thousands of linear limit rows and the dense nonlinear torque rows best):
- rest: q(0) = q_start, qd(0) = qdd(0) = 0, hence at rest at q_start at every period's end
  (linear equalities);
- joint positions inside [lower + m, upper - m] with m = ``position_margin`` x the range (joints
  without limits: q_start +- ``free_excursion``); velocities within ``velocity_fraction`` x the
  URDF's limits; accelerations within the given limits: linear inequalities on a grid of
  ``LIMIT_POINTS_PER_HARMONIC`` points per period and harmonic;
- torques of the URDF model plus the description's plant friction within ``torque_fraction``
  x the description's ``torque_limits`` (nonlinear, on the objective's knots; gradients by
  central differences of the regressor), posed as |Y theta + fv qd| <= limit - |fc|: the
  Coulomb term jumps by 2 fc at every reversal, between any two knots (posed with its smooth
  sign at the knots, the PUMA's torque peaked 16 % above the limit between them);
- no collision: Drake's ``MinimumDistanceLowerBoundConstraint`` (signed distances of every
  SceneGraph collision candidate pair >= ``min_distance``) at the knots, when the URDF has
  collision geometry.
After the solve, every limit and the distances are checked again on a dense grid (the robot's
rate over one period; distances at ``DISTANCE_CHECK_POINTS_PER_HARMONIC`` points per harmonic);
should anything fail between the knots, the motion about q_start is scaled down until it passes
(``scale`` in the result; 1.0 when nothing was needed).

Band: the highest harmonic K / T_p stays below ``max_frequency`` (default a quarter of the
repair's 8 Hz cut-off, ``identification.data.DEFAULT_CUTOFF_HZ``: its zero-phase order-4
filter passes 2 Hz with |H|^2 = 1 - 1.5e-5, so the filter keeps the designed motion and F).
The repair trims ``2 / f_c`` (0.25 s) at both ends of a log; the motion is at rest there.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.excitation.fourier import FourierTrajectory, basis, random_feasible, rest_constraints
from robust_drake.excitation.information import (InformationModel, check_effect_kinds, condition_number,
                                                  dependent_columns, information, log_det, predicted_std)

#: longest period [s] of the designed motion (Swevers et al.'s 0.1 Hz fundamental); a longer
#: experiment repeats it an integer number of times
MAX_PERIOD = 10.0
#: most harmonics per joint by default (n (2K + 1) unknowns; 8 keeps the Panda's program at 119)
MAX_HARMONICS = 8
#: joints without position limits move at most this far from q_start [rad] (the default
#: excitation's peak, ``logs_to_control.excitation_for``)
FREE_EXCURSION = 1.0
#: objective and torque knots per period and harmonic (the regressor's derivatives at them are the
#: design's whole cost); the torque holds several times the motion's band, so its peaks between
#: the knots are caught on the dense grid after the solve and the bounds tightened
#: (MAX_REFINEMENTS)
KNOTS_PER_HARMONIC = 8
#: position / velocity / acceleration grid per period and harmonic for the linear limit rows
LIMIT_POINTS_PER_HARMONIC = 24
#: grid [Hz] of the reported information matrices (scaled to the log's rate)
INFO_RATE = 250.0
#: signed-distance check points per period and harmonic after the solve
DISTANCE_CHECK_POINTS_PER_HARMONIC = 24


@dataclass
class ExcitationConfig:
    """What :func:`design_excitation` designs (SI units; None = the rule of the module docstring).

    Parameters
    ----------
    robot : str
        Robot name (``robust_drake/robots``) or URDF path.
    duration : float
        Experiment length [s], a whole number of periods.
    period : float or None
        Period [s]; default min(duration, MAX_PERIOD) dividing the duration.
    harmonics : int or None
        Harmonics per joint; default floor(max_frequency x period), at most MAX_HARMONICS.
    max_frequency : float or None
        Band limit [Hz]; default a quarter of the identification filter's cut-off (2 Hz).
    start : tuple or None
        Rest pose [rad] at both ends; default the middle of each joint's limits, 0 without.
    position_margin : float
        Share of each joint's range kept free at both ends (default 0.05).
    free_excursion : float
        Largest distance [rad] from the start of a joint without position limits (default 1).
    velocity_limits, acceleration_limits, torque_limits : float, sequence or None
        Per joint [rad/s, rad/s^2, N m]; default the URDF's velocity limits, no acceleration
        limit, the robot description's ``torque_limits``.
    velocity_fraction, torque_fraction : float
        Shares of the velocity and torque limits the motion may use (0.9, 0.8: headroom for the
        tracking loop).
    effects : tuple of str
        Effect kinds (``robust_drake.effects``) added to the information (``--for-effects``).
    min_distance : float
        Smallest signed distance [m] between collision geometries at the knots.
    collision : bool
        Use the URDF's collision geometry (when it has any).
    rate : float or None
        Sample rate [Hz] of the written reference; default the description's ``sample_rate``.
    noise_std : float or None
        Torque noise [N m] per sample for the predicted standard deviations; default 2 % of the
        largest gravity torque (the repo's simulated experiments).
    seed : int
        Seed of the starting point and of the default excitation compared with.
    starts : int
        Random starting points tried (the best log det is kept).
    max_iterations : int
        SNOPT major iterations per solve.
    """

    robot: str
    duration: float = 10.0
    period: float | None = None
    harmonics: int | None = None
    max_frequency: float | None = None
    start: tuple | None = None
    position_margin: float = 0.05
    free_excursion: float = FREE_EXCURSION
    velocity_limits: object = None
    acceleration_limits: object = None
    torque_limits: object = None
    velocity_fraction: float = 0.9
    torque_fraction: float = 0.8
    effects: tuple = ()
    min_distance: float = 0.01
    collision: bool = True
    rate: float | None = None
    noise_std: float | None = None
    seed: int = 0
    starts: int = 1
    max_iterations: int = 300


@dataclass
class ExcitationResult:
    """The designed experiment: ``trajectory`` (FourierTrajectory), its samples at ``rate``
    (``t``, ``q``, ``qd``, ``qdd`` (N, n), ``tau`` the model torque), and ``report`` (JSON-ready:
    objective, log_det, condition_number, predicted standard deviations against the default
    excitation, the limits' margins, the solver)."""

    config: ExcitationConfig
    trajectory: FourierTrajectory
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    report: dict = field(default_factory=dict)
    joint_names: list = field(default_factory=list)

    def __call__(self, t):
        """(q, qd, qdd) at t [s]: the trajectory (a :class:`~robust_drake.trajectories.Reference`
        function; periodic, at rest at q_start at multiples of the period)."""
        return self.trajectory(t)

    def reference(self):
        """The motion as a :class:`robust_drake.trajectories.Reference` named ``excitation``."""
        from robust_drake.trajectories import Reference

        return Reference(self.trajectory, self.trajectory.n, float(self.config.duration), "excitation",
                         {"period": self.trajectory.period, "harmonics": self.trajectory.harmonics})

    def to_csv(self, path) -> str:
        """Write ``t, q1..qn, qd1..qdn, qdd1..qddn`` (s, rad, rad/s, rad/s^2; 1-based column
        numbers as the repo's canonical log CSV) at the robot's rate; returns the path."""
        from robust_drake.trajectories import write_trajectory_csv

        return write_trajectory_csv(path, self.t, self.q, self.qd, self.qdd)

    def to_dict(self) -> dict:
        return dict(self.report)

    def figure(self):
        """Joint positions, velocities, accelerations and torques over one period with their
        limits, and the predicted standard deviation of every parameter (designed vs default)."""
        from robust_drake.excitation.plots import excitation_figure

        return excitation_figure(self)

    def plot(self, folder) -> list[str]:
        """Write ``excitation.png`` and ``information.png`` into ``folder``; returns the paths."""
        from robust_drake.excitation.plots import write_plots

        return write_plots(self, folder)


# ------------------------------------------------------------------------------------ set-up
@dataclass
class _Problem:
    n: int
    names: list
    period: float
    harmonics: int
    q_start: np.ndarray
    q_lo: np.ndarray
    q_hi: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    tau_max: np.ndarray | None
    limits: dict


def _vector(x, n, what):
    if x is None:
        return None
    a = np.asarray(x, float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,) or np.any(~(a > 0)):
        raise RobustDrakeError(f"{what} must be one positive number or {n} positive numbers (got {x!r})")
    return a


def period_and_harmonics(cfg: ExcitationConfig) -> tuple[float, int, float]:
    """(period [s], harmonics, band limit [Hz]) by the rules of the module docstring."""
    from robust_drake.identification.data import DEFAULT_CUTOFF_HZ

    T = float(cfg.duration)
    if not (math.isfinite(T) and T > 0):
        raise RobustDrakeError(f"duration must be a positive number of seconds (got {cfg.duration!r})")
    f_max = DEFAULT_CUTOFF_HZ / 4.0 if cfg.max_frequency is None else float(cfg.max_frequency)
    if not 0 < f_max < DEFAULT_CUTOFF_HZ:
        raise RobustDrakeError(f"max_frequency must lie in (0, {DEFAULT_CUTOFF_HZ:g}) Hz, below the identification "
                               f"filter's cut-off (got {cfg.max_frequency!r})")
    if cfg.period is None:
        periods = max(1, math.ceil(T / MAX_PERIOD - 1e-9))
        Tp = T / periods
    else:
        Tp = float(cfg.period)
        periods = T / Tp if Tp > 0 else 0
        if not (Tp > 0 and abs(periods - round(periods)) < 1e-9 and round(periods) >= 1):
            raise RobustDrakeError(f"the duration ({T:g} s) must be a whole number of periods (period {cfg.period!r} s)")
    K = cfg.harmonics if cfg.harmonics is not None else min(MAX_HARMONICS, int(math.floor(f_max * Tp + 1e-9)))
    if int(K) < 1:
        raise RobustDrakeError(f"no harmonic fits below {f_max:g} Hz with a {Tp:g} s period: use a longer duration "
                               "or a higher max_frequency")
    if K / Tp > f_max + 1e-9:
        raise RobustDrakeError(f"{K} harmonics of a {Tp:g} s period reach {K / Tp:g} Hz, above the band limit "
                               f"{f_max:g} Hz (identification filter cut-off {DEFAULT_CUTOFF_HZ:g} Hz)")
    return Tp, int(K), f_max


def _problem(cfg: ExcitationConfig, plant, desc) -> _Problem:
    from robust_drake.models import JointLimits

    n = plant.num_velocities()
    Tp, K, f_max = period_and_harmonics(cfg)
    lim = JointLimits.from_plant(plant)
    lo, hi = lim.arrays()
    finite = np.isfinite(lo) & np.isfinite(hi)
    if cfg.start is None:
        q0 = np.where(finite, 0.5 * (np.where(finite, lo, 0) + np.where(finite, hi, 0)), 0.0)
    else:
        q0 = np.asarray(cfg.start, float).ravel()
        if q0.shape != (n,) or not np.all(np.isfinite(q0)):
            raise RobustDrakeError(f"start pose must be {n} finite numbers [rad] (got {cfg.start!r})")
    m = float(cfg.position_margin)
    if not 0 <= m < 0.5:
        raise RobustDrakeError(f"position_margin must lie in [0, 0.5) (got {cfg.position_margin!r})")
    rng_w = np.where(finite, hi - lo, 0.0)
    q_lo = np.where(np.isfinite(lo), lo + m * rng_w, q0 - cfg.free_excursion)
    q_hi = np.where(np.isfinite(hi), hi - m * rng_w, q0 + cfg.free_excursion)
    bad = np.flatnonzero((q0 < q_lo) | (q0 > q_hi))
    if bad.size:
        j = int(bad[0])
        raise RobustDrakeError(f"start pose of joint {j + 1} ({lim.names[j]}) = {q0[j]:.4g} rad lies outside "
                               f"[{q_lo[j]:.4g}, {q_hi[j]:.4g}] rad (its limits less the {m:.0%} margin)")
    v_urdf = np.asarray(plant.GetVelocityUpperLimits(), float)
    v_max = _vector(cfg.velocity_limits, n, "velocity_limits")
    v_max = np.where(np.isfinite(v_urdf), v_urdf, np.inf) if v_max is None else v_max
    v_max = v_max * float(cfg.velocity_fraction)
    a_urdf = np.asarray(plant.GetAccelerationUpperLimits(), float)
    a_max = _vector(cfg.acceleration_limits, n, "acceleration_limits")
    a_max = np.where(np.isfinite(a_urdf), a_urdf, np.inf) if a_max is None else a_max
    t_lim = _vector(cfg.torque_limits, n, "torque_limits")
    if t_lim is None and desc.torque_limits is not None:
        t_lim = np.broadcast_to(np.asarray(desc.torque_limits, float), (n,)).copy()
    tau_max = None if t_lim is None else t_lim * float(cfg.torque_fraction)
    limits = {"position": {"lower": q_lo.tolist(), "upper": q_hi.tolist(),
                           "rule": f"URDF limits less {m:.0%} of the range; q_start +- {cfg.free_excursion:g} rad "
                                   "without limits"},
              "velocity": v_max.tolist(), "acceleration": a_max.tolist(),
              "torque": None if tau_max is None else tau_max.tolist(),
              "velocity_fraction": cfg.velocity_fraction, "torque_fraction": cfg.torque_fraction,
              "band_hz": f_max}
    return _Problem(n, list(lim.names), Tp, K, q0, q_lo, q_hi, v_max, a_max, tau_max, limits)


class _Collision:
    """Drake diagram (plant + SceneGraph) of the arm for distance queries, or inactive when the
    URDF has no collision geometry (``active`` False, ``pairs`` 0)."""

    def __init__(self, robot, min_distance: float, enabled: bool = True):
        from pydrake.geometry import Role
        from pydrake.systems.framework import DiagramBuilder

        from robust_drake.models import add_arm

        builder = DiagramBuilder()
        self.plant, self.scene_graph = add_arm(builder, robot)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        self.sg_context = self.scene_graph.GetMyContextFromRoot(self.context)
        insp = self.scene_graph.model_inspector()
        self.geometries = insp.NumGeometriesWithRole(Role.kProximity)
        self.pairs = len(insp.GetCollisionCandidates()) if self.geometries else 0
        self.active = bool(enabled and self.pairs)
        self.min_distance = float(min_distance)
        self._constraint = None

    def constraint(self):
        if self._constraint is None:
            from pydrake.multibody.inverse_kinematics import MinimumDistanceLowerBoundConstraint

            self._constraint = MinimumDistanceLowerBoundConstraint(
                self.plant, self.min_distance, self.plant_context, None, 0.05)
        return self._constraint

    def min_distance_along(self, q) -> tuple[float, str]:
        """Smallest signed distance [m] over the configurations q (M, n), and the pair."""
        if not self.pairs:
            return math.inf, ""
        insp = self.scene_graph.model_inspector()
        best, where = math.inf, ""
        for qk in np.atleast_2d(q):
            self.plant.SetPositions(self.plant_context, qk)
            qo = self.scene_graph.get_query_output_port().Eval(self.sg_context)
            for d in qo.ComputeSignedDistancePairwiseClosestPoints(max_distance=1.0):
                if d.distance < best:
                    best = float(d.distance)
                    where = f"{insp.GetName(d.id_A)} / {insp.GetName(d.id_B)}"
        return best, where


# ------------------------------------------------------------------------------------ the program
class _Evaluator:
    """Objective -log det F and the torque rows with their gradients in x, cached per x."""

    def __init__(self, model: InformationModel, prob: _Problem, knots: int):
        self.model, self.prob = model, prob
        self.n, self.m = prob.n, 2 * prob.harmonics + 1
        self.tk = np.arange(knots) * prob.period / knots
        self.B = [basis(self.tk, prob.period, prob.harmonics, r) for r in (0, 1, 2)]
        self.scale = None
        self._key = None
        self.evaluations = 0

    def states(self, x):
        X = np.asarray(x, float).reshape(self.n, self.m)
        return tuple(B @ X.T for B in self.B)

    def set_scale(self, x):
        A = self.model.columns(*self.states(x))
        nrm = np.sqrt(np.mean(A.reshape(-1, A.shape[-1]) ** 2, axis=0))
        self.scale = 1.0 / np.where(nrm > 0, nrm, 1.0)

    def _at(self, x):
        key = np.asarray(x, float).tobytes()
        if key == self._key:
            return
        self.evaluations += 1
        q, qd, qdd = self.states(x)
        A, tau, dA, dtau = self.model.with_derivatives(q, qd, qdd)
        s = self.scale
        As = A * s
        M, n, p = As.shape
        F = np.einsum("kap,kaq->pq", As, As)
        F += 1e-12 * np.trace(F) / p * np.eye(p)
        sign, ld = np.linalg.slogdet(F)
        Finv = np.linalg.inv(F)
        W = As @ Finv  # (M, n, p)
        gz = 2.0 * np.einsum("kap,skap->sk", W, dA * s)  # d logdet / d z_s(t_k)
        grad = np.zeros((self.n, self.m))
        jac = np.zeros((M, n, self.n, self.m))
        for r in range(3):
            for j in range(self.n):
                sidx = r * self.n + j
                grad[j] += gz[sidx] @ self.B[r]
                jac[:, :, j, :] += dtau[sidx][:, :, None] * self.B[r][:, None, :]
        self._key = key
        self.f = -ld if sign > 0 else 1e6
        self.g = -grad.ravel()
        self.tau = tau.ravel()
        self.J = jac.reshape(M * n, self.n * self.m)

    def cost(self, x):
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue

        if x.dtype != object:
            self._at(x)
            return self.f
        xv = ExtractValue(x).ravel()
        self._at(xv)
        return AutoDiffXd(self.f, self.g @ ExtractGradient(x))

    def torque(self, x):
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if x.dtype != object:
            self._at(x)
            return self.tau.copy()
        self._at(ExtractValue(x).ravel())
        return InitializeAutoDiff(self.tau, self.J @ ExtractGradient(x)).ravel()


def _collision_eval(col: _Collision, Bk: np.ndarray, n: int, m: int):
    """Constraint function of x for one knot: Drake's minimum-distance constraint at q = B x."""
    c = col.constraint()

    def f(x):
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

        if x.dtype != object:
            X = x.reshape(n, m)
            return c.Eval(X @ Bk)
        xv = ExtractValue(x).ravel()
        G = np.zeros((n, n * m))
        for j in range(n):
            G[j, j * m:(j + 1) * m] = Bk
        q_ad = InitializeAutoDiff(xv.reshape(n, m) @ Bk, G @ ExtractGradient(x))
        return c.Eval(q_ad.ravel())

    return f, c.lower_bound(), c.upper_bound()


def _solve(prob: _Problem, ev: _Evaluator, col: _Collision, x0, max_iterations: int):
    from pydrake.solvers import MathematicalProgram, SnoptSolver, SolverOptions

    n, m, K, Tp = prob.n, 2 * prob.harmonics + 1, prob.harmonics, prob.period
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(n * m, "x")
    Aeq, beq = rest_constraints(n, Tp, K, prob.q_start)
    prog.AddLinearEqualityConstraint(Aeq, beq, x)
    tg = np.arange(LIMIT_POINTS_PER_HARMONIC * K) * Tp / (LIMIT_POINTS_PER_HARMONIC * K)
    B0, B1, B2 = (basis(tg, Tp, K, r) for r in (0, 1, 2))
    for j in range(n):
        xj = x[j * m:(j + 1) * m]
        prog.AddLinearConstraint(B0, np.full(len(tg), prob.q_lo[j]), np.full(len(tg), prob.q_hi[j]), xj)
        if np.isfinite(prob.v_max[j]):
            prog.AddLinearConstraint(B1, np.full(len(tg), -prob.v_max[j]), np.full(len(tg), prob.v_max[j]), xj)
        if np.isfinite(prob.a_max[j]):
            prog.AddLinearConstraint(B2, np.full(len(tg), -prob.a_max[j]), np.full(len(tg), prob.a_max[j]), xj)
    prog.AddCost(ev.cost, x)
    if prob.tau_max is not None:
        M = len(ev.tk)
        # |Y theta + fv qd| + |fc| <= limit: the Coulomb term's sign switches between the knots
        lim = np.tile(np.maximum(prob.tau_max - np.abs(ev.model.coulomb), 1e-9 * prob.tau_max), M)
        prog.AddConstraint(ev.torque, -lim, lim, x, description="torque")
    if col.active:
        Bc = ev.B[0]  # at the knots (checked densely after the solve)
        for k in range(Bc.shape[0]):
            f, lb, ub = _collision_eval(col, Bc[k], n, m)
            prog.AddConstraint(f, lb, ub, x, description=f"distance_{k}")
    prog.SetInitialGuess(x, x0)
    opts = SolverOptions()
    sid = SnoptSolver().solver_id()
    opts.SetOption(sid, "Major iterations limit", int(max_iterations))
    opts.SetOption(sid, "Major optimality tolerance", 1e-4)
    opts.SetOption(sid, "Major feasibility tolerance", 1e-6)
    opts.SetOption(sid, "Iterations limit", 100000)
    solver = SnoptSolver()
    if not solver.available() or not solver.enabled():
        raise RobustDrakeError("the excitation design needs SNOPT, which this pydrake build does not provide")
    res = solver.Solve(prog, x0, opts)
    return res.GetSolution(x), res, prog


# ------------------------------------------------------------------------------------ checks
def _grid(duration: float, rate: float) -> np.ndarray:
    N = int(round(duration * rate))
    return np.arange(N + 1) / rate


def check_limits(traj: FourierTrajectory, prob: _Problem, model: InformationModel, col: _Collision,
                 rate: float) -> dict:
    """Margins of the motion over one period on the dense grid ``rate`` [Hz] (distances at
    DISTANCE_CHECK_POINTS_PER_HARMONIC points per harmonic): each as a dict per joint; ``ok``
    when every limit holds there."""
    t = np.arange(int(math.ceil(traj.period * rate)) + 1) / rate
    q, qd, qdd = traj(t)
    tau = model.torque(q, qd, qdd)
    out = {"grid_hz": rate, "points": int(len(t))}
    out["position"] = {"min_to_lower": (q.min(axis=0) - prob.q_lo).tolist(),
                       "min_to_upper": (prob.q_hi - q.max(axis=0)).tolist()}
    ok = bool(np.all(q >= prob.q_lo - 1e-9) and np.all(q <= prob.q_hi + 1e-9))
    with np.errstate(divide="ignore", invalid="ignore"):
        for key, val, lim in (("velocity", qd, prob.v_max), ("acceleration", qdd, prob.a_max),
                              ("torque", tau, prob.tau_max)):
            peak = np.abs(val).max(axis=0)
            if lim is None:
                out[key] = {"peak": peak.tolist(), "fraction_of_limit": None}
                continue
            frac = np.where(np.isfinite(lim), peak / lim, 0.0)
            out[key] = {"peak": peak.tolist(),
                        "fraction_of_limit": [float(f) if np.isfinite(lj) else None for f, lj in zip(frac, lim)]}
            ok &= bool(np.all(frac <= 1.0 + 1e-6))
    if col.pairs:
        td = np.arange(DISTANCE_CHECK_POINTS_PER_HARMONIC * traj.harmonics) * traj.period / (
            DISTANCE_CHECK_POINTS_PER_HARMONIC * traj.harmonics)
        dmin, pair = col.min_distance_along(traj(td)[0])
        out["distance"] = {"min": dmin, "pair": pair, "bound": col.min_distance, "points": int(len(td)),
                           "collision_pairs": col.pairs}
        ok &= bool(dmin >= 0.0)
    else:
        out["distance"] = {"min": None, "pair": "", "bound": None, "collision_pairs": 0,
                           "note": "the URDF has no collision geometry: no distance constraint"}
    out["ok"] = bool(ok)
    return out


def scaled(traj: FourierTrajectory, q_start, s: float) -> FourierTrajectory:
    """The motion about q_start scaled by s (q - q_start, qd, qdd all x s; still at rest)."""
    X = traj.coefficients.copy()
    K = traj.harmonics
    X[:, 1:] *= s
    X[:, 0] = np.asarray(q_start, float) - X[:, K + 1:].sum(axis=1)
    return FourierTrajectory(X, traj.period)


# ------------------------------------------------------------------------------------ default
def default_reference(robot, seed: int = 0):
    """The repo's default identification excitation (``logs_to_control.excitation_for``: random
    Fourier sum, 0.1 Hz, 5 harmonics, peak 1 rad about the middle of the limits), as
    ``simulate_experiment`` draws it with this seed."""
    from robust_drake.experiments.logs_to_control import excitation_for
    from robust_drake.synthetic.simulated import FourierReference
    from robust_drake.models import make_plant

    exc = excitation_for(robot)
    n = make_plant(robot).num_velocities()
    amp = np.broadcast_to(np.asarray(exc["amplitude"], float), (n,))
    return FourierReference.random(n, np.random.default_rng(seed), amp, 0.1, 5, exc["offset"])


def experiment_information(model: InformationModel, reference, duration: float, rate: float):
    """(F, A) of a log of ``reference`` [q, qd, qdd](t) over [trim, duration - trim] at ``rate``
    [Hz], trim = the repair's 2 / f_c (``identification.data``)."""
    from robust_drake.identification.data import DEFAULT_CUTOFF_HZ

    trim = 2.0 / DEFAULT_CUTOFF_HZ
    t = _grid(duration, rate)
    t = t[(t >= trim - 1e-12) & (t <= duration - trim + 1e-12)]
    A = model.columns(*reference(t))
    return information(A), A


# ------------------------------------------------------------------------------------ driver
def design_excitation(config: ExcitationConfig | None = None, progress=None, **fields) -> ExcitationResult:
    """Design the experiment ``config`` describes (module docstring); ``progress(message)`` is
    called at each stage (default: the ``robust_drake`` logger).  Raises
    :class:`RobustDrakeError` (one line) on a bad configuration or when no start satisfies the
    limits."""
    from robust_drake.description import describe
    from robust_drake.log import get_logger
    from robust_drake.models import make_plant, resolve_urdf
    from robust_drake.regressor import InverseDynamicsRegressor

    if config is None:
        config = ExcitationConfig(**fields)
    elif fields:
        raise RobustDrakeError(f"give either an ExcitationConfig or fields, not both (got {sorted(fields)})")
    cfg = config
    log = progress or get_logger().info
    t_start = time.perf_counter()
    resolve_urdf(cfg.robot)
    plant = make_plant(cfg.robot)
    desc = describe(cfg.robot)
    prob = _problem(cfg, plant, desc)
    n = prob.n
    reg = InverseDynamicsRegressor.from_robot(cfg.robot)
    pf = desc.plant_friction or {}
    effects = check_effect_kinds(cfg.effects, n, cfg.robot)
    model = InformationModel(reg, effects, pf.get("coulomb"), pf.get("viscous"))
    from robust_drake.description import DEFAULT_RATE

    rate = float(cfg.rate or desc.sample_rate or DEFAULT_RATE)
    rng = np.random.default_rng(cfg.seed)
    half = 0.45 * np.minimum(prob.q_hi - prob.q_start, prob.q_start - prob.q_lo)
    x0 = random_feasible(n, prob.period, prob.harmonics, prob.q_start, np.maximum(half, 1e-3), rng)
    model, dropped = _drop_span_effects(model, reg, effects, pf, prob, x0, log)
    ev = _Evaluator(model, prob, KNOTS_PER_HARMONIC * prob.harmonics)
    col = _Collision(cfg.robot, cfg.min_distance, cfg.collision)
    log(f"excite: {cfg.robot}, {n} joints, period {prob.period:g} s x {round(cfg.duration / prob.period)}, "
        f"{prob.harmonics} harmonics (<= {prob.harmonics / prob.period:.3g} Hz), {model.p} parameters, "
        f"{n * (2 * prob.harmonics + 1)} unknowns, collision pairs {col.pairs}")
    # the start must respect the torque limits: shrink the random motion until it does
    traj0 = FourierTrajectory.from_vector(x0, n, prob.period)
    for _ in range(30):
        if check_limits(traj0, prob, model, _NoCollision(), _check_rate(prob))["ok"]:
            break
        traj0 = scaled(traj0, prob.q_start, 0.7)
    ev.set_scale(traj0.vector())
    best = None
    for s in range(max(1, int(cfg.starts))):
        xs = traj0.vector() if s == 0 else scaled(FourierTrajectory.from_vector(
            random_feasible(n, prob.period, prob.harmonics, prob.q_start, np.maximum(half, 1e-3), rng), n,
            prob.period), prob.q_start, 0.5).vector()
        traj, info = _solve_refined(prob, ev, col, xs, model, cfg.max_iterations)
        log(f"excite: start {s}: {info['status']} after {info['seconds']:.1f} s ({info['evaluations']} evaluations)")
        if best is None or _logdet_of(model, traj, prob) > _logdet_of(model, best[0], prob):
            best = (traj, info)
    traj, info = best
    traj, chk, scale_applied = _checked(traj, prob, model, col, rate, cfg.robot, info)
    if scale_applied < 1.0:
        log(f"excite: motion scaled by {scale_applied:.3f} so every limit holds on the {rate:g} Hz grid")
    result = _result(cfg, prob, model, traj, rate, chk, info, scale_applied, dropped, col)
    result.report["seconds"] = time.perf_counter() - t_start
    log(f"excite: log det {result.report['log_det']:.2f} (default {result.report['default']['log_det']:.2f}), "
        f"median std ratio {result.report['median_std_ratio']:.3g}, {result.report['seconds']:.1f} s")
    return result


def _drop_span_effects(model, reg, effects, pf, prob, x0, log):
    """(model, dropped names): effect columns inside the rigid-body span (no motion identifies
    them) left out of the information."""
    if not effects:
        return model, []
    tk = np.arange(KNOTS_PER_HARMONIC * prob.harmonics) * prob.period / (KNOTS_PER_HARMONIC * prob.harmonics)
    A0 = model.columns(*FourierTrajectory.from_vector(x0, prob.n, prob.period)(tk))
    dep = dependent_columns(A0, model.p_base + 2 * prob.n)
    if not dep:
        return model, []
    dropped = [model.names[c] for c in dep]
    keep = [e for e in effects if not any(nm.startswith(e.name + ":") for nm in dropped)]
    log(f"excite: {', '.join(dropped)} lie in the span of the base parameters (no motion tells them apart); "
        "left out of the information")
    return InformationModel(reg, keep, pf.get("coulomb"), pf.get("viscous")), dropped


def _solve_refined(prob, ev, col, xs, model, max_iterations):
    """Solve; tighten the bounds by what the dense grid finds violated between the knots; solve
    again from there (at most MAX_REFINEMENTS times).  Returns (trajectory, solver info)."""
    t0 = time.perf_counter()
    ps, rounds = prob, 0
    while True:
        x, res, _ = _solve(ps, ev, col, xs, max_iterations)
        ev._key = None
        trial = FourierTrajectory.from_vector(x, prob.n, prob.period)
        tight = _tightened(ps, prob, trial, model, _check_rate(prob))
        if tight is None or rounds >= MAX_REFINEMENTS:
            break
        ps, xs, rounds = tight, x, rounds + 1
    info = {"solver": res.get_solver_id().name(), "status": str(res.get_solution_result()),
            "success": bool(res.is_success()), "seconds": time.perf_counter() - t0,
            "evaluations": ev.evaluations, "refinements": rounds}
    return trial, info


def _checked(traj, prob, model, col, rate, robot, info):
    """(trajectory, margins, scale): the dense-grid check at the robot's rate; the motion about
    q_start scaled down (1 % steps) until every limit holds there, or a one-line error."""
    scale = 1.0
    chk = check_limits(traj, prob, model, col, rate)
    out = traj
    while not chk["ok"] and scale > 0.05:
        scale *= 0.99
        out = scaled(traj, prob.q_start, scale)
        chk = check_limits(out, prob, model, col, _check_rate(prob))
        if chk["ok"]:  # confirmed on the robot's rate
            chk = check_limits(out, prob, model, col, rate)
    if not chk["ok"]:
        raise RobustDrakeError(f"no excitation of {robot!r} satisfies the limits on the dense grid (solver "
                               f"{info['status']}); relax the limits, the start pose or min_distance")
    return out, chk, scale


class _NoCollision:
    pairs = 0
    min_distance = None


#: points per period and harmonic of the intermediate dense-grid checks (starting point,
#: refinements); the final check runs at the robot's rate
CHECK_POINTS_PER_HARMONIC = 128


def _check_rate(prob) -> float:
    return CHECK_POINTS_PER_HARMONIC * prob.harmonics / prob.period


#: re-solves with bounds tightened by what the dense grid found between the knots
MAX_REFINEMENTS = 3


def _tightened(ps: _Problem, prob: _Problem, traj, model, rate) -> _Problem | None:
    """``ps`` (the bounds solved with) tightened so the motion's dense-grid peaks come back inside
    ``prob``'s limits (position box shrunk by the overshoot, velocity / acceleration / torque
    bounds scaled by limit / peak, 0.5 % extra); None when nothing is violated."""
    import dataclasses

    t = np.arange(int(math.ceil(traj.period * rate)) + 1) / rate
    q, qd, qdd = traj(t)
    tau = model.torque(q, qd, qdd)
    lo_over = np.maximum(prob.q_lo - q.min(axis=0), 0.0)
    hi_over = np.maximum(q.max(axis=0) - prob.q_hi, 0.0)
    changed = bool(np.any(lo_over > 1e-9) or np.any(hi_over > 1e-9))
    upd = {"q_lo": ps.q_lo + np.where(lo_over > 1e-9, 1.05 * lo_over + 1e-4, 0.0),
           "q_hi": ps.q_hi - np.where(hi_over > 1e-9, 1.05 * hi_over + 1e-4, 0.0)}
    for key, val in (("v_max", qd), ("a_max", qdd), ("tau_max", tau)):
        lim, cur = getattr(prob, key), getattr(ps, key)
        if lim is None:
            continue
        peak = np.abs(val).max(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            over = np.isfinite(lim) & (peak > lim * (1 + 1e-6))
            factor = np.where(over, 0.995 * lim / np.where(peak > 0, peak, 1.0), 1.0)
        if over.any():
            changed = True
        upd[key] = cur * factor
    return dataclasses.replace(ps, **upd) if changed else None


def _logdet_of(model, traj, prob) -> float:
    tk = np.arange(KNOTS_PER_HARMONIC * prob.harmonics) * prob.period / (KNOTS_PER_HARMONIC * prob.harmonics)
    return log_det(information(model.columns(*traj(tk))))


def _result(cfg, prob, model, traj, rate, chk, info, scale_applied, dropped, col) -> ExcitationResult:
    from robust_drake.experiments.logs_to_control import torque_noise_std

    t = _grid(cfg.duration, rate)
    q, qd, qdd = traj(t)
    # exactly at rest at q_start at every period's end (the series gives it to ~1e-16)
    ends = np.flatnonzero(np.abs(t / prob.period - np.round(t / prob.period)) < 1e-9)
    q[ends], qd[ends], qdd[ends] = prob.q_start, 0.0, 0.0
    P = prob.period * rate  # samples per period: the torque repeats with the motion
    if abs(P - round(P)) < 1e-9 and round(P) < len(t):
        P = int(round(P))
        tau = model.torque(q[:P], qd[:P], qdd[:P])[np.arange(len(t)) % P]
    else:
        tau = model.torque(q, qd, qdd)
    sigma = cfg.noise_std
    if sigma is None:
        try:
            sigma = torque_noise_std(cfg.robot, 0.02) or 0.005
        except RobustDrakeError:
            sigma = 0.005
    rate_log = rate
    # F grows with the samples for a motion well inside the band: computed on an INFO_RATE grid and
    # scaled to the log's rate (the rate changes the predicted std by sqrt(rate / INFO_RATE), not
    # the comparison with the default)
    info_rate = min(rate_log, INFO_RATE)
    F, A = experiment_information(model, traj, cfg.duration, info_rate)
    F0, A0 = experiment_information(model, default_reference(cfg.robot, cfg.seed), cfg.duration, info_rate)
    F, F0 = F * (rate_log / info_rate), F0 * (rate_log / info_rate)
    sd = predicted_std(F / sigma ** 2)
    sd0 = predicted_std(F0 / sigma ** 2)
    ratio = sd0 / sd
    p = model.p
    ld, ld0 = log_det(F / sigma ** 2), log_det(F0 / sigma ** 2)
    report = {
        "robot": str(cfg.robot), "joint_names": prob.names, "duration": float(cfg.duration),
        "period": prob.period, "periods": int(round(cfg.duration / prob.period)), "harmonics": prob.harmonics,
        "max_frequency_hz": prob.harmonics / prob.period, "rate": rate, "start": prob.q_start.tolist(),
        "objective": "log det of the Fisher information of the base parameters, friction and effects "
                     "(D-optimal; see excitation.design)",
        "parameters": list(model.names), "effects": [e.name for e in model.effects], "effects_left_out": dropped,
        "noise_std": float(sigma),
        "log_det": ld, "condition_number": condition_number(A),
        "predicted_std": sd.tolist(),
        "default": {"log_det": ld0, "condition_number": condition_number(A0), "predicted_std": sd0.tolist(),
                    "excitation": "logs_to_control.excitation_for (0.1 Hz, 5 harmonics, seed "
                                  f"{cfg.seed}), same duration, rate and trim"},
        "std_ratio": ratio.tolist(), "median_std_ratio": float(np.median(ratio)),
        "volume_ratio_per_parameter": float(math.exp((ld - ld0) / (2 * p))) if np.isfinite(ld - ld0) else None,
        "limits": prob.limits, "margins": chk, "scale": scale_applied, "solver": info,
        "collision_geometry": bool(col.pairs),
        "csv_columns": ["t"] + [f"q{j + 1}" for j in range(prob.n)] + [f"qd{j + 1}" for j in range(prob.n)]
                       + [f"qdd{j + 1}" for j in range(prob.n)],
    }
    return ExcitationResult(cfg, traj, t, q, qd, qdd, tau, report, prob.names)
