"""Library of candidate effects: each one is both extra regressor columns and a Drake block.

An *effect* is a torque term that the rigid-body + Coulomb + viscous baseline lacks. Each effect
kind is a subclass of :class:`Effect` registered in :data:`EFFECTS` under its exact kind name.
One effect *instance* has a joint (0-based, or ``None`` for a global effect) and fixed shape
parameters (Stribeck velocity, transition velocity, harmonic number, ...); what remains is linear
in a few coefficients, so the instance can be fitted by least squares together with the baseline.

Sign convention (one for the whole library)
-------------------------------------------
The plant moves under ``M(q) qdd + c(q, qd) + g(q) = tau + f_e`` where ``tau`` is the commanded
(= recorded) motor torque and ``f_e`` is the effect's ``generalized_force`` block output, summed
into the plant's ``applied_generalized_force`` input. The identification model is therefore::

    tau_measured = Y(q, qd, qdd) theta + sum_e  Phi_e @ coef_e ,   Phi_e @ coef_e = -f_e

i.e. the columns ``Phi_e`` (``Effect.columns``) times the coefficients are the extra torque the
motor has to supply because of the effect, and the block outputs exactly minus that. Friction-like
effects with positive coefficients therefore oppose motion in the plant.

Three effects cannot be written as a force computed from (state, tau):
- ``rotor_inertia`` (``-I_r qdd``) and ``payload`` need the acceleration, which a block cannot
  read without an algebraic loop. They change the plant instead: :meth:`Effect.apply_to_plant`
  (before ``Finalize``) sets the joint actuator's reflected inertia / welds a point mass to the
  last link; their ``block`` returns ``None``. Drake's mass matrix and inverse dynamics then
  contain the term, so forward simulation is exact.
- ``time_delay`` delays the commanded torque. Its block is a discrete delay line with input
  ``tau`` whose ``generalized_force`` is ``tau(t - d) - tau(t)``; summed with ``tau`` the plant
  receives ``tau(t - d)``. Its columns are the first-order expansion
  ``tau(t) - tau(t - d) ~= d * dtau/dt``, so ``columns @ coef`` and ``-block`` agree to O(d^2).

Nonlinear shape parameters are fixed per candidate (a small grid in :meth:`Effect.candidates`).
Discontinuous signs are written with the smooth sign ``tanh(qd / v_eps)`` (``v_eps`` = 0.01 rad/s
by default) in both the columns and the blocks, so the two agree exactly and the plant can be
integrated with an error-controlled integrator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.errors import RobustDrakeError

V_EPS = 0.01  # rad/s, smooth-sign width used unless an effect is given another


def smooth_sign(v, v_eps=V_EPS):
    """tanh(v / v_eps): the sign function with a transition of width ~v_eps (rad/s)."""
    return np.tanh(np.asarray(v, dtype=float) / v_eps)


def time_derivative(t, x, segment=None):
    """Central differences of x (N, n) on the time stamps, separately within each file segment
    (never across the jump between concatenated files)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    out = np.zeros_like(x)
    seg = np.zeros(len(t), dtype=int) if segment is None else np.asarray(segment)
    for s in np.unique(seg):
        m = seg == s
        if m.sum() >= 2:
            out[m] = np.gradient(x[m], t[m], axis=0)
    return out


def _fmt(x):
    return f"{x:g}" if isinstance(x, (int, float)) else str(x)


#: upper bound of a ``time_delay`` [s] when the robot description declares a bus but no
#: ``bus_latency``: a few cycles of a 0.5-1 kHz driver loop on a field bus
DEFAULT_BUS_DELAY = 0.02


@dataclass(frozen=True)
class PhysicalContext:
    """What an admissibility rule may compare a fitted parameter with (:meth:`Effect.admissible`).

    ``coulomb`` / ``viscous``: the same fit's Coulomb [N m] and viscous [N m s/rad] levels per
    joint; ``tau_max``: max |tau_j| in the data [N m]; ``duration``: the longest run [s] (time
    since the run's t = 0); ``band_hz``: (2 / T_file, f_c) [Hz], the band a periodic residual can
    be told from a drift and is not removed by the filter; ``max_delay``: the delay bound [s] from
    the robot description (None: the description declares no physical source of delay);
    ``configurations``: joint positions of the data [rad or m] (a configuration-dependent
    torque's peak over the data)."""

    coulomb: tuple | None = None
    viscous: tuple | None = None
    tau_max: tuple | None = None
    duration: float | None = None
    band_hz: tuple | None = None
    max_delay: float | None = None
    #: (M, n) joint angles [rad] (or positions [m]) of the data, at most
    #: :data:`CONTEXT_CONFIGURATIONS` rows evenly spread over the log: what a configuration-
    #: dependent torque is evaluated on (``configuration_dependent``'s explained RMS)
    configurations: np.ndarray | None = None

    @classmethod
    def from_data(cls, data, robot=None) -> "PhysicalContext":
        seg = np.asarray(getattr(data, "segment", np.zeros(len(data.t), int)))
        t = np.asarray(data.t, float)
        spans = [float(t[seg == s][-1] - t[seg == s][0]) for s in np.unique(seg)]
        fc = getattr(getattr(data, "filter", None), "cutoff_hz", None)
        band = (2.0 / max(np.median(spans), 1e-9), float(fc) if fc else 0.5 / float(data.dt))
        return cls(tau_max=tuple(float(x) for x in np.max(np.abs(data.tau), axis=0)),
                   duration=float(np.max(t) - min(0.0, float(np.min(t)))), band_hz=band,
                   max_delay=delay_bound(robot)[0] if robot is not None else None,
                   configurations=subsample_configurations(data.q))

    def with_friction(self, theta, names) -> "PhysicalContext":
        """This context with the Coulomb / viscous levels ``fc<j+1>`` / ``fv<j+1>`` of a fit."""
        th = dict(zip(names, np.asarray(theta, float)))
        n = sum(1 for k in th if k.startswith("fc"))
        return replace(self, coulomb=tuple(float(th[f"fc{j + 1}"]) for j in range(n)),
                       viscous=tuple(float(th[f"fv{j + 1}"]) for j in range(n)))


#: at most this many configurations are kept in a :class:`PhysicalContext`
CONTEXT_CONFIGURATIONS = 4000


def subsample_configurations(q, rows: int = CONTEXT_CONFIGURATIONS) -> np.ndarray:
    """Every k-th row of q (N, n), k = ceil(N / rows): at most ``rows`` rows spread over the log."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return q[::max(1, -(-len(q) // rows))].copy()


def delay_bound(robot) -> tuple[float | None, str]:
    """(bound [s], source text) of a ``time_delay`` from the robot description: a declared
    ``bus_latency`` L gives 2 L (a command crosses the bus and the driver's loop); a declared
    ``bus`` without latency :data:`DEFAULT_BUS_DELAY`; no bus: (None, why) -- a delay has no
    physical source (e.g. a direct-drive arm with analog amplifiers) and is not offered."""
    from robust_drake.description import describe

    try:
        hw = describe(robot)
    except RobustDrakeError:
        return None, "no robot description"
    if hw.bus_latency is not None:
        return 2.0 * float(hw.bus_latency), f"{hw.bus or 'bus'} latency {hw.bus_latency:g} s (robot description)"
    if hw.bus:
        return DEFAULT_BUS_DELAY, f"{hw.bus} bus (robot description)"
    return None, f"the robot description ({hw.drive} drive) declares no bus or bus_latency"


def check_bounds(parameters: dict, bounds: dict) -> str:
    """'' if every named parameter (scalar or per-joint list) lies in its [lo, hi], else why."""
    for name, (lo, hi) in bounds.items():
        if name not in parameters:
            continue
        vals = np.atleast_1d(np.asarray(parameters[name], dtype=float))
        if np.any(~np.isfinite(vals)) or np.any(vals < lo) or np.any(vals > hi):
            return f"{name} = {np.round(vals, 4).tolist()} outside [{lo:g}, {hi:g}]"
    return ""


def _joint_values(effect, values, n: int) -> np.ndarray:
    """A context's per-joint array restricted to the joints the effect acts on."""
    return np.asarray(values, float)[effect.joints(n)]


def _limit_by(effect, parameters: dict, name: str, context, attr: str, what: str, absolute: bool = True) -> str:
    """|parameter| <= the context's per-joint ``attr`` (e.g. the torque range)."""
    ref = getattr(context, attr, None) if context is not None else None
    if ref is None or name not in parameters:
        return ""
    vals = np.atleast_1d(np.asarray(parameters[name], float))
    lim = _joint_values(effect, ref, len(ref))
    v = np.abs(vals) if absolute else vals
    if np.any(v > lim + 1e-12):
        return f"|{name}| = {np.round(np.abs(vals), 4).tolist()} above {what} {np.round(lim, 4).tolist()}"
    return ""


class Effect:
    """One candidate effect (kind + joint + fixed shape parameters).

    Subclasses define ``kind``, ``coef_names`` (per joint), ``_features`` (pure, vectorised) and
    ``parameters`` / ``coef_from_parameters`` (the map between fitted coefficients and named SI
    parameters). Per-joint kinds given ``joint=None`` act on every joint with separate
    coefficients; ``shared`` kinds (one physical quantity for the whole arm, e.g. a delay) use one
    coefficient for all joints when ``joint`` is None.

    ``joint`` is a 0-based index into the arm's joints (as numpy's, ``q[:, joint]``); the label
    :attr:`name` numbers joints from 1 like every report, message and CSV column:
    ``Spring(joint=5).name == "spring[6]"``, the spring on joint 6 (``q6``).
    """

    kind: ClassVar[str] = ""
    coef_names: ClassVar[tuple[str, ...]] = ("c",)
    needs_tau: ClassVar[bool] = False  # the block has a "tau" input
    needs_qdd: ClassVar[bool] = False  # the columns use acceleration
    modifies_plant: ClassVar[bool] = False  # realised by apply_to_plant, block() is None
    shared: ClassVar[bool] = False  # joint=None -> one coefficient shared by all joints
    default_shape: ClassVar[dict] = {}
    #: physically admissible range [lo, hi] of each named parameter (:meth:`parameters`), per
    #: joint; a user-defined kind declares its own (and may override :meth:`admissible`)
    bounds: ClassVar[dict] = {}

    def __init__(self, joint: int | None = None, **shape):
        unknown = set(shape) - set(self.default_shape)
        if unknown:
            raise RobustDrakeError(
                f"effect {self.kind!r}: unknown shape parameter(s) {sorted(unknown)}; "
                f"known: {sorted(self.default_shape)}")
        self.joint = None if joint is None else int(joint)
        self.shape = {**self.default_shape, **shape}

    # -- identity ------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        j = "all" if self.joint is None else str(self.joint + 1)  # labels number joints from 1 (README)
        sh = ",".join(f"{k}={_fmt(v)}" for k, v in self.shape.items() if k != "robot")
        return f"{self.kind}[{j}]" + (f"({sh})" if sh else "")

    def __repr__(self):
        return f"<Effect {self.name}>"

    def joints(self, n: int) -> list[int]:
        if self.joint is None:
            return list(range(n))
        if not 0 <= self.joint < n:
            raise RobustDrakeError(f"effect {self.kind}: joint index {self.joint} (0-based) out of range for {n} joints")
        return [self.joint]

    def num_coef(self, n: int) -> int:
        if self.shared and self.joint is None:
            return len(self.coef_names)
        return len(self.coef_names) * len(self.joints(n))

    # -- regressor side ------------------------------------------------------------------------
    def _features(self, j, q, qd, qdd, tau, taud):
        """Features of joint j, arrays (N, len(coef_names)); q, qd, ... are (N, n)."""
        raise NotImplementedError

    def column_names(self, n: int) -> list[str]:
        if self.shared and self.joint is None:
            return [f"{self.kind}:{c}" for c in self.coef_names]
        return [f"{self.kind}:{c}{j + 1}" for j in self.joints(n) for c in self.coef_names]

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None) -> np.ndarray:
        """Pure function: the (N, n, k) columns from arrays (N, n) (missing ones only if unused)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        cols = np.zeros((N, n, self.num_coef(n)))
        m = len(self.coef_names)
        for i, j in enumerate(self.joints(n)):
            f = self._features(j, q, qd, qdd, tau, taud)
            if self.shared and self.joint is None:
                cols[:, j, :] = f
            else:
                cols[:, j, i * m:(i + 1) * m] = f
        return cols

    def columns(self, data) -> tuple[np.ndarray, list[str]]:
        """Extra regressor columns (N, n, k) and their names, from an ``IdentData``-like object
        with (N, n) arrays ``t, q, qd, qdd, tau`` (``taud`` optional, else d tau/dt by central
        differences of ``data.tau``)."""
        q = np.asarray(data.q, dtype=float)
        taud = None
        if getattr(self, "uses_taud", False):
            taud = getattr(data, "taud", None)
            if taud is None:
                taud = time_derivative(data.t, data.tau, getattr(data, "segment", None))
        cols = self.evaluate_columns(q, getattr(data, "qd", None), getattr(data, "qdd", None),
                                     getattr(data, "tau", None), taud)
        return cols, self.column_names(q.shape[1])

    @classmethod
    def candidates(cls, n_joints: int, **context) -> list["Effect"]:
        """Instances to try: one per joint over the class's shape grid ``shape_grid``."""
        grid = getattr(cls, "shape_grid", [{}])
        return [cls(joint=j, **sh) for j in range(n_joints) for sh in grid]

    # -- parameters ----------------------------------------------------------------------------
    def parameters(self, coef) -> dict:
        """Named SI parameters from the fitted coefficients (length ``num_coef``).
        Per-joint kinds with joint=None give lists (one entry per joint)."""
        coef = np.asarray(coef, dtype=float).ravel()
        m = len(self.coef_names)
        if len(coef) % m:
            raise RobustDrakeError(f"{self.name}: expected a multiple of {m} coefficients, got {len(coef)}")
        per = [self._parameters_one(coef[i:i + m]) for i in range(0, len(coef), m)]
        out = dict(per[0]) if len(per) == 1 else {k: [p[k] for p in per] for k in per[0]}
        for k, v in self.shape.items():
            if k != "robot":
                out.setdefault(k, v)
        return out

    def coef_from_parameters(self, parameters: dict, n: int) -> np.ndarray:
        """Inverse of :meth:`parameters`: the coefficient vector (num_coef(n),)."""
        k = self.num_coef(n)
        m = len(self.coef_names)
        reps = k // m
        out = []
        for i in range(reps):
            p = {key: (val[i] if isinstance(val, (list, tuple, np.ndarray)) and key not in self.shape else val)
                 for key, val in parameters.items()}
            out.extend(self._coef_one(p))
        return np.asarray(out, dtype=float)

    def _parameters_one(self, c) -> dict:
        return {self.coef_names[i]: float(c[i]) for i in range(len(c))}

    def _coef_one(self, p) -> list[float]:
        return [float(p[name]) for name in self.coef_names]

    def admissible(self, parameters: dict, context: PhysicalContext | None = None) -> str:
        """'' if the fitted ``parameters`` are physically admissible, else the reason. The
        default checks :attr:`bounds`; kinds whose limit depends on the data or the rest of the
        fit (friction levels, torque range, duration) extend it with ``context``. Shape
        parameters count too."""
        return check_bounds({**self.shape, **parameters}, self.bounds)

    # -- plant side ----------------------------------------------------------------------------
    def generalized_force(self, q, qd, tau, coef) -> np.ndarray:
        """What the block outputs for one state: -(columns @ coef), shape (n,)."""
        q = np.atleast_2d(q)
        cols = self.evaluate_columns(q, np.atleast_2d(qd), None,
                                     None if tau is None else np.atleast_2d(tau), None)
        return -(cols[0] @ np.asarray(coef, dtype=float))

    def block(self, n: int, parameters: dict, **kw) -> LeafSystem | None:
        """Plant-side LeafSystem: input ``state`` (2n) [and ``tau`` (n)], output
        ``generalized_force`` (n). ``None`` for effects realised by :meth:`apply_to_plant`."""
        return EffectForceBlock(self, n, self.coef_from_parameters(parameters, n))

    def apply_to_plant(self, plant, parameters: dict) -> None:
        """Change the (not yet finalised) MultibodyPlant; no-op for force-type effects."""

    def apply_to_context(self, plant, context, parameters: dict) -> None:
        """Post-Finalize alternative to :meth:`apply_to_plant` for plant-modifying effects: change
        the parameters in a plant context instead (use one or the other, never both).
        No-op for force-type effects."""


class EffectForceBlock(LeafSystem):
    """Stateless block: ``generalized_force = -(columns(state, tau) @ coef)``."""

    def __init__(self, effect: Effect, n: int, coef):
        super().__init__()
        self.effect, self.n = effect, n
        self.coef = np.asarray(coef, dtype=float).copy()
        self.set_name(f"effect_{effect.kind}_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self._tau = self.DeclareVectorInputPort("tau", n) if effect.needs_tau else None
        self.DeclareVectorOutputPort("generalized_force", n, self._calc)

    def _calc(self, context, output):
        x = self._state.Eval(context)
        n = self.n
        tau = self._tau.Eval(context) if self._tau is not None else None
        output.SetFromVector(self.effect.generalized_force(x[:n], x[n:], tau, self.coef))


# ---------------------------------------------------------------------------------------------
# The kinds
# ---------------------------------------------------------------------------------------------
class Stribeck(Effect):
    """Stribeck friction excess: ``(F_s - F_c) exp(-(qd/v_s)^2) sign(qd)`` (Gaussian shape).

    Coefficient ``stribeck_torque`` = F_s - F_c [N m] (breakaway minus Coulomb level), shape
    ``stribeck_velocity`` v_s [rad/s]."""

    kind = "stribeck"
    coef_names = ("stribeck_torque",)
    #: F_s >= F_c: the breakaway level is above the Coulomb level (a level *below* it at low
    #: speed is not Stribeck friction)
    bounds = {"stribeck_torque": (0.0, math.inf)}
    default_shape = {"stribeck_velocity": 0.1, "v_eps": V_EPS}
    shape_grid = [{"stribeck_velocity": v} for v in (0.05, 0.1, 0.2, 0.4)]

    def _features(self, j, q, qd, qdd, tau, taud):
        v = qd[:, j]
        vs = self.shape["stribeck_velocity"]
        return (np.exp(-(v / vs) ** 2) * smooth_sign(v, self.shape["v_eps"]))[:, None]


class SmoothCoulomb(Effect):
    """Coulomb friction with a gradual transition: ``F_c tanh(qd/v_0)`` or
    ``F_c (2/pi) atan(qd/v_0)``. Fitted next to the baseline's sharp sign(qd) column, the
    coefficient is the share of the Coulomb level that switches gradually."""

    kind = "smooth_coulomb"
    coef_names = ("coulomb",)
    #: the gradually switching share of the Coulomb level is a friction level: >= 0
    bounds = {"coulomb": (0.0, math.inf)}
    default_shape = {"transition_velocity": 0.3, "form": "tanh"}
    shape_grid = [{"transition_velocity": v} for v in (0.1, 0.3, 1.0)]

    def _features(self, j, q, qd, qdd, tau, taud):
        v = qd[:, j] / self.shape["transition_velocity"]
        if self.shape["form"] == "atan":
            return (2.0 / math.pi * np.arctan(v))[:, None]
        if self.shape["form"] != "tanh":
            raise RobustDrakeError("smooth_coulomb form must be 'tanh' or 'atan'")
        return np.tanh(v)[:, None]


class AsymmetricCoulomb(Effect):
    """Direction-dependent Coulomb level: ``F_c+ `` for qd > 0, ``F_c-`` for qd < 0.

    With the baseline's symmetric ``F_c sign(qd)`` this adds ``a |sign(qd)|`` where the
    coefficient ``asymmetry`` a = (F_c+ - F_c-)/2 [N m]. Unlike a torque offset it vanishes at
    rest, so only data with slow phases / reversals separate the two."""

    kind = "asymmetric_coulomb"
    coef_names = ("asymmetry",)
    default_shape = {"v_eps": 0.02}
    shape_grid = [{"v_eps": 0.02}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return np.abs(smooth_sign(qd[:, j], self.shape["v_eps"]))[:, None]

    def admissible(self, parameters, context=None):
        """Both directional levels F_c +- a non-negative: |a| <= F_c (the same fit's)."""
        return _limit_by(self, parameters, "asymmetry", context, "coulomb", "the Coulomb level")


class LoadDependentFriction(Effect):
    """Friction growing with the transmitted load (gear friction): ``mu |tau| sign(qd)``.
    Coefficient ``load_coefficient`` mu (dimensionless). Block input ``tau`` = commanded torque."""

    kind = "load_dependent_friction"
    coef_names = ("load_coefficient",)
    #: friction grows with the transmitted load (mu >= 0); mu > 1 would make the gear lose more
    #: than it transmits
    bounds = {"load_coefficient": (0.0, 1.0)}
    needs_tau = True
    default_shape = {"v_eps": V_EPS}
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return (np.abs(tau[:, j]) * smooth_sign(qd[:, j], self.shape["v_eps"]))[:, None]


class PositionDependent(Effect):
    """Position-periodic torque (cogging, ripple, cable): ``a sin(h q) + b cos(h q)``,
    harmonic h per revolution fixed per candidate. Parameters: ``amplitude`` A = hypot(a, b)
    [N m], ``phase`` phi with A sin(h q + phi), and the raw ``sin`` / ``cos`` coefficients."""

    kind = "position_dependent"
    coef_names = ("sin", "cos")
    default_shape = {"harmonic": 4}
    #: every harmonic 1-12 per revolution: cogging of a motor with S slots and P poles repeats
    #: lcm(S, P) times per motor revolution, torque ripple of a drive at multiples of the pole
    #: pairs / phases; 5/rev and 7/rev (the 6k -+ 1 harmonics of a three-phase drive) were missing
    #: from the earlier grid (2, 3, 4, 6, 8, 12), issue 21. On a joint whose gravity torque is a
    #: first harmonic of its own angle (the first horizontal axis) harmonic 1 lies in the
    #: rigid-body span and the fit rejects it as not identifiable.
    shape_grid = [{"harmonic": h} for h in range(1, 13)]

    def _features(self, j, q, qd, qdd, tau, taud):
        h = self.shape["harmonic"]
        return np.stack([np.sin(h * q[:, j]), np.cos(h * q[:, j])], axis=1)

    def _parameters_one(self, c):
        a, b = float(c[0]), float(c[1])
        return {"amplitude": math.hypot(a, b), "phase": math.atan2(b, a), "sin": a, "cos": b}

    def admissible(self, parameters, context=None):
        """Cogging / ripple amplitude <= the largest torque the joint carried in the data."""
        return _limit_by(self, parameters, "amplitude", context, "tau_max", "max |tau|")

    def _coef_one(self, p):
        if "sin" in p and "cos" in p:
            return [float(p["sin"]), float(p["cos"])]
        A, phi = float(p["amplitude"]), float(p.get("phase", 0.0))
        return [A * math.cos(phi), A * math.sin(phi)]


class TorqueOffset(Effect):
    """Constant torque bias (sensor / current offset, unmodelled static load): ``offset`` [N m]."""

    kind = "torque_offset"
    coef_names = ("offset",)
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return np.ones((q.shape[0], 1))

    def admissible(self, parameters, context=None):
        """Either sign; |offset| <= the largest torque the joint carried in the data."""
        return _limit_by(self, parameters, "offset", context, "tau_max", "max |tau|")


class TorqueScale(Effect):
    """Motor-constant error: the joint receives ``(1 + gain_error) tau`` for a commanded tau.
    Columns ``-tau_j`` with coefficient ``gain_error`` (dimensionless).

    Identifiability: scaling every joint's torque by the same factor only rescales theta, so
    only the gains *relative to each other* are identifiable from free rigid-body fits, and
    candidates are per joint. On a 2-joint arm, gain (1 + e) on joint 1 is indistinguishable from
    gain 1 / (1 + e) on joint 0 (see :func:`equivalent_gain_error`); which joint is "wrong"
    needs an absolute reference (a known mass or a torque sensor)."""

    kind = "torque_scale"
    coef_names = ("gain_error",)
    #: a motor constant wrong by more than 50 %, or -> -1 (the trivial "model = 0" solution of an
    #: errors-in-variables column), is no motor-constant error
    bounds = {"gain_error": (-0.5, 0.5)}
    needs_tau = True
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return -tau[:, j:j + 1]


def equivalent_gain_error(gain_error: float) -> float:
    """On a 2-joint arm: the gain error on the *other* joint that explains the same data,
    (1 + e') = 1 / (1 + e) (a common factor is absorbed by theta)."""
    return 1.0 / (1.0 + gain_error) - 1.0


class RotorInertia(Effect):
    """Reflected motor inertia ``I_r qdd_j`` on the diagonal of M (``reflected_inertia`` = rotor
    inertia x gear ratio^2, kg m^2). Realised in the plant by the joint actuator's rotor inertia
    (an actuator is added if the joint has none). On the first joint of a serial arm it merges
    with the first link's inertia (not identifiable); the columns are still given."""

    kind = "rotor_inertia"
    coef_names = ("reflected_inertia",)
    bounds = {"reflected_inertia": (0.0, math.inf)}  # an inertia is >= 0
    needs_qdd = True
    modifies_plant = True
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        if qdd is None:
            raise RobustDrakeError("rotor_inertia columns need accelerations (data.qdd)")
        return qdd[:, j:j + 1]

    def block(self, n, parameters, **kw):
        return None

    def apply_to_plant(self, plant, parameters):
        from pydrake.multibody.tree import JointActuatorIndex
        vals = parameters["reflected_inertia"]
        # Pre-Finalize: the arm's 1-dof joints in index order are its coordinates 0..n-1.
        joints = [plant.get_joint(ji) for ji in plant.GetJointIndices()
                  if plant.get_joint(ji).num_velocities() == 1]
        js = self.joints(len(joints))
        vals = list(vals) if isinstance(vals, (list, tuple, np.ndarray)) else [vals] * len(js)
        for j, Ir in zip(js, vals):
            joint = joints[j]
            act = None
            for ai in plant.GetJointActuatorIndices():
                a = plant.get_joint_actuator(ai)
                if a.joint().index() == joint.index():
                    act = a
            if act is None:
                act = plant.AddJointActuator(f"rotor_{j}", joint)
            G = act.default_gear_ratio()
            act.set_default_rotor_inertia(act.default_rotor_inertia() + float(Ir) / (G * G))

    def apply_to_context(self, plant, context, parameters):
        """Post-Finalize alternative to :meth:`apply_to_plant` (use one, not both): raise the
        joint actuator's rotor inertia in ``context``. Needs an actuator on the joint."""
        vals = parameters["reflected_inertia"]
        js = self.joints(plant.num_velocities())
        vals = list(vals) if isinstance(vals, (list, tuple, np.ndarray)) else [vals] * len(js)
        for j, Ir in zip(js, vals):
            act = None
            for ai in plant.GetJointActuatorIndices():
                a = plant.get_joint_actuator(ai)
                if a.joint().num_velocities() == 1 and a.joint().velocity_start() == j:
                    act = a
            if act is None:
                raise RobustDrakeError(f"rotor_inertia: joint {j + 1} has no actuator; use apply_to_plant "
                                       "(load_plant(robot, effects)) before Finalize instead")
            G = act.gear_ratio(context)
            act.SetRotorInertia(context, act.rotor_inertia(context) + float(Ir) / (G * G))


class Spring(Effect):
    """Joint-space spring (cables, balancing spring): the plant gets ``-stiffness q_j`` (rest at
    the joint zero; a rest-angle offset shows up as a separate torque_offset). [N m/rad]"""

    kind = "spring"
    coef_names = ("stiffness",)
    #: a passive spring restores (k >= 0); a negative stiffness would feed energy in
    bounds = {"stiffness": (0.0, math.inf)}
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return q[:, j:j + 1]


class TimeDelay(Effect):
    """Delay ``delay`` d [s] between the recorded command and the torque the plant receives.
    Columns: d tau_j/dt (first-order expansion, see module docstring); joint=None means one delay
    shared by all joints. Block: :class:`TorqueDelayLine`."""

    kind = "time_delay"
    coef_names = ("delay",)
    needs_tau = True
    shared = True
    uses_taud = True
    shape_grid = [{}]
    bounds = {"delay": (0.0, math.inf)}  # causal

    def _features(self, j, q, qd, qdd, tau, taud):
        if taud is None:
            raise RobustDrakeError("time_delay columns need d tau/dt")
        return taud[:, j:j + 1]

    @classmethod
    def candidates(cls, n_joints, robot=None, **context):
        """Offered only when the robot description declares a physical source (:func:`delay_bound`):
        the column d tau/dt correlates with any residual that leads the torque, and would absorb
        it as a 'delay' on an arm that has none."""
        if robot is None or delay_bound(robot)[0] is None:
            return []
        return [cls(joint=None)] + [cls(joint=j) for j in range(n_joints)]

    def admissible(self, parameters, context=None):
        """0 <= d <= the description's bound (``context.max_delay``; None: no source, rejected)."""
        why = check_bounds(parameters, self.bounds)
        if why or context is None:
            return why
        if context.max_delay is None:
            return "no physical source of a delay in the robot description (bus / bus_latency)"
        return check_bounds(parameters, {"delay": (0.0, context.max_delay)})

    def block(self, n, parameters, sample_period=None, **kw):
        d = parameters["delay"]
        delays = np.zeros(n)
        js = self.joints(n)
        delays[js] = d if np.isscalar(d) else np.asarray(d, dtype=float)
        return TorqueDelayLine(n, delays, sample_period or 1e-3)


class TorqueDelayLine(LeafSystem):
    """Discrete delay line on the commanded torque (per-joint delays ``delays`` [s]).

    Samples input ``tau`` every ``period`` into a history buffer; output ``generalized_force`` =
    tau(t - d) - tau(t), tau(t - d) linearly interpolated between the current input and the
    stored samples. Before the first samples exist the history holds zeros."""

    def __init__(self, n, delays, period):
        super().__init__()
        self.n = n
        self.delays = np.asarray(delays, dtype=float)
        if np.any(self.delays < 0):
            raise RobustDrakeError("time_delay: delay must be >= 0")
        self.period = float(period)
        self.K = int(math.ceil(self.delays.max() / self.period)) + 2
        self.set_name("effect_time_delay")
        self._tau = self.DeclareVectorInputPort("tau", n)
        self.DeclareVectorInputPort("state", 2 * n)  # unused; keeps the common port layout
        # state: [t_last, buffer (K x n) newest first]
        self._x = self.DeclareDiscreteState(1 + self.K * n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.all_sources_ticket()})

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._x).get_value()
        new = discrete_state.get_mutable_vector(self._x).get_mutable_value()
        n, K = self.n, self.K
        new[0] = context.get_time()
        new[1 + n:] = x[1:1 + (K - 1) * n]
        new[1:1 + n] = self._tau.Eval(context)

    def _calc(self, context, output):
        x = context.get_discrete_state(self._x).get_value()
        t = context.get_time()
        tau = self._tau.Eval(context)
        n, K = self.n, self.K
        buf = x[1:].reshape(K, n)
        ts = x[0] - self.period * np.arange(K)
        out = np.zeros(n)
        for j in range(n):
            d = self.delays[j]
            if d <= 0:
                continue
            target = t - d
            times = np.concatenate(([t], ts))[::-1]
            vals = np.concatenate(([tau[j]], buf[:, j]))[::-1]
            out[j] = np.interp(target, times, vals, left=vals[0]) - tau[j]
        output.SetFromVector(out)


class Payload(Effect):
    """Point mass ``mass`` [kg] at the tool (a point fixed in the last link, ``tool_position``
    in that body's frame, default from the robot's ArmSpec / the last link's COM direction).

    Columns: inverse dynamics of a 1 kg point mass at the tool (with gravity), computed with the
    Drake plant of ``robot`` (given to :func:`make_effect` / ``candidates(robot=...)`` or found
    as ``data.robot``). Realised in the plant by welding a point-mass body to the last link.

    Identifiability: a mass rigidly attached to the last link only changes that link's inertial
    parameters, so when all base parameters are fitted freely the payload is absorbed by them
    (its column lies in the span of the rigid-body regressor); it is separable only against a
    prior / nominal rigid-body model."""

    kind = "payload"
    bounds = {"mass": (0.0, math.inf)}
    coef_names = ("mass",)
    modifies_plant = True
    needs_qdd = True
    shared = True
    default_shape = {"robot": None, "tool_position": None}

    @classmethod
    def candidates(cls, n_joints, robot=None, **context):
        return [cls(joint=None, robot=robot)]

    def _tool(self, plant):
        return _tool_point(plant, self.shape["tool_position"])

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None, robot=None):
        robot = robot or self.shape["robot"]
        if robot is None:
            raise RobustDrakeError("payload columns need the robot (make_effect('payload', robot=...))")
        if qd is None or qdd is None:
            raise RobustDrakeError("payload columns need qd and qdd")
        plant, context, body, p = _payload_plant(robot, self.shape["tool_position"])
        q, qd, qdd = (np.atleast_2d(a) for a in (q, qd, qdd))
        N, n = q.shape
        from pydrake.multibody.tree import MultibodyForces
        f = MultibodyForces(plant)
        cols = np.zeros((N, n, 1))
        for i in range(N):
            plant.SetPositions(context, q[i])
            plant.SetVelocities(context, qd[i])
            plant.CalcForceElementsContribution(context, f)
            cols[i, :, 0] = plant.CalcInverseDynamics(context, qdd[i], f)
        return cols

    def columns(self, data):
        robot = self.shape["robot"] or getattr(data, "robot", None)
        cols = self.evaluate_columns(data.q, data.qd, data.qdd, robot=robot)
        return cols, self.column_names(np.asarray(data.q).shape[1])

    def block(self, n, parameters, **kw):
        return None

    def mass_from_base_shift(self, data, regressor, theta_base, theta_base_nominal=None) -> float:
        """Payload mass implied by a fitted rigid-body model that absorbed it.

        A tool mass lies in the span of the rigid-body regressor (class docstring), so a free
        fit absorbs it into the base parameters. Its size is recovered by projecting the torque
        difference between the fitted and the nominal (URDF) base parameters onto the payload
        column: ``m = <Phi, Y_b dtheta> / <Phi, Phi>`` over the samples of ``data``
        (``Y_b`` = ``regressor.evaluate``, ``dtheta = theta_base - theta_base_nominal``).
        """
        Yb = np.asarray(regressor.evaluate(data.q, data.qd, data.qdd), float)
        if theta_base_nominal is None:
            theta_base_nominal = regressor.base_parameters()
        dtau = Yb @ (np.asarray(theta_base, float) - np.asarray(theta_base_nominal, float))
        robot = self.shape["robot"] or getattr(data, "robot", None)
        phi = self.evaluate_columns(data.q, data.qd, data.qdd, robot=robot)[:, :, 0]
        return float(np.sum(phi * dtau) / np.sum(phi * phi))

    def apply_to_context(self, plant, context, parameters):
        """Post-Finalize alternative to :meth:`apply_to_plant` (use one, not both): add the point
        mass to the tool body's spatial inertia in ``context``."""
        from pydrake.multibody.tree import SpatialInertia, UnitInertia
        m = float(parameters["mass"])
        body, p = self._tool(plant)
        M = body.CalcSpatialInertiaInBodyFrame(context)
        M += SpatialInertia(m, p, UnitInertia.PointMass(p), skip_validity_check=True)
        body.SetSpatialInertiaInBodyFrame(context, M)

    def apply_to_plant(self, plant, parameters):
        from pydrake.math import RigidTransform
        from pydrake.multibody.tree import SpatialInertia, UnitInertia
        m = float(parameters["mass"])
        body, p = self._tool(plant)
        pl = plant.AddRigidBody("payload", body.model_instance(),
                                SpatialInertia(m, np.zeros(3), UnitInertia(0.0, 0.0, 0.0),
                                               skip_validity_check=True))
        plant.WeldFrames(body.body_frame(), pl.body_frame(), RigidTransform(p))


def _last_body(plant):
    """The child body of the arm's last 1-dof joint (joint index order; works pre-Finalize)."""
    joints = [plant.get_joint(ji) for ji in plant.GetJointIndices()
              if plant.get_joint(ji).num_velocities() == 1]
    if not joints:
        raise RobustDrakeError("payload: the model has no 1-dof joint")
    return joints[-1].child_body()


def _tool_point(plant, tool_position=None):
    """(body, p_BT): the tool point. ``tool_position`` (in the last link's frame) if given, else
    the frame named ``tool`` (URDF ``<frame name="tool" link=...>``) if the model has one, else
    twice the last link's COM offset (the far end of a uniform rod)."""
    if tool_position is not None:
        return _last_body(plant), np.asarray(tool_position, dtype=float)
    if plant.HasFrameNamed("tool"):
        frame = plant.GetFrameByName("tool")
        return frame.body(), np.asarray(frame.GetFixedPoseInBodyFrame().translation(), dtype=float)
    body = _last_body(plant)
    return body, 2.0 * np.asarray(body.default_com(), dtype=float)


_PAYLOAD_CACHE: dict = {}


def _payload_plant(robot, tool_position):
    """A plant of ``robot`` whose links are massless except a 1 kg point at the tool."""
    key = (str(robot), None if tool_position is None else tuple(tool_position))
    if key in _PAYLOAD_CACHE:
        return _PAYLOAD_CACHE[key]
    from pydrake.multibody.tree import SpatialInertia, UnitInertia
    plant = load_plant(robot)
    context = plant.CreateDefaultContext()
    body, p = _tool_point(plant, tool_position)
    from pydrake.multibody.tree import BodyIndex
    zero = SpatialInertia(0.0, np.zeros(3), UnitInertia(0.0, 0.0, 0.0), skip_validity_check=True)
    for bi in range(1, plant.num_bodies()):
        plant.get_body(BodyIndex(bi)).SetSpatialInertiaInBodyFrame(context, zero)
    body.SetSpatialInertiaInBodyFrame(
        context, SpatialInertia(1.0, p, UnitInertia.PointMass(p), skip_validity_check=True))
    for ai in plant.GetJointActuatorIndices():  # no reflected rotor inertia either
        plant.get_joint_actuator(ai).SetRotorInertia(context, 0.0)
    out = (plant, context, body, p)
    _PAYLOAD_CACHE[key] = out
    return out


def load_plant(robot, effects=(), time_step=0.0, builder=None):
    """``robust_drake.models.make_plant`` (or ``add_arm`` into ``builder``) with the
    plant-modifying effects [(Effect, parameters), ...] applied before ``Finalize``. Returns the
    plant."""
    from robust_drake.models import add_arm, make_plant

    def apply(plant):
        for eff, params in effects:
            eff.apply_to_plant(plant, params)

    if builder is not None:
        return add_arm(builder, robot, time_step=time_step, before_finalize=apply)[0]
    return make_plant(robot, time_step=time_step, before_finalize=apply)


def resolve_robot_path(robot) -> str:
    """Path of ``robot``'s model file (``robust_drake.models.resolve_urdf``)."""
    from robust_drake.models import resolve_urdf

    return str(resolve_urdf(robot))


class PreslidingFriction(Effect):
    """Presliding (Dahl) friction: a friction component that builds up over a small displacement
    after every velocity reversal instead of switching at once.

    Dahl's model in the displacement domain (Dahl 1968; the rate-independent limit of LuGre,
    Canudas de Wit et al. 1995 eq. 1 with sigma_1 = 0): with ``x0`` =
    ``presliding_displacement`` [rad] (the displacement over which the friction state settles)
    ::

        dz/dt = (qd - |qd| z) / x0 ,      z in [-1, 1],      torque = F_d z

    so z -> sign(qd) after a motion of a few x0 in one direction and lags behind sign(qd) for
    ~x0 after a reversal (a hysteresis loop in the friction-vs-position plane; a rate-independent
    friction lag, not a time delay). Coefficient ``presliding_torque`` F_d [N m]: fitted next to
    the baseline's sharp ``F_c sign(qd)``, F_d > 0 means part of the Coulomb level is reached
    only gradually after a reversal (presliding compliance of gear teeth / bearings, backlash
    being taken up). Dahl's model has F_d >= 0; the selection rejects a negative fit (a
    breakaway that decays after a reversal is the ``stribeck`` kind), see
    :attr:`bounds`.

    Columns: z integrated along each file's filtered positions (exact solution for a piecewise
    monotone sample path: z_{k+1} = s + (z_k - s) exp(-|dq|/x0), s = sign(dq)), starting at
    z = 0. ``x0`` is a fixed shape parameter per candidate, so the columns are linear in F_d.
    Block: :class:`PreslidingFrictionBlock` (continuous state z per joint, output -F_d z).
    """

    kind = "presliding_friction"
    coef_names = ("presliding_torque",)
    #: Dahl's model has F_d >= 0 (a level higher just after a reversal that decays is a
    #: breakaway: the ``stribeck`` kind); x0 > 0
    bounds = {"presliding_torque": (0.0, math.inf), "presliding_displacement": (1e-12, math.inf)}
    default_shape = {"presliding_displacement": 0.01}
    shape_grid = [{"presliding_displacement": x} for x in (0.003, 0.01, 0.03)]

    def _features(self, j, q, qd, qdd, tau, taud):
        return presliding_state(q[:, j], self.shape["presliding_displacement"])[:, None]

    def columns(self, data):
        q = np.asarray(data.q, dtype=float)
        N, n = q.shape
        seg = getattr(data, "segment", None)
        seg = np.zeros(N, dtype=int) if seg is None else np.asarray(seg)
        cols = np.zeros((N, n, self.num_coef(n)))
        for s in np.unique(seg):
            m = seg == s
            cols[m] = self.evaluate_columns(q[m])
        return cols, self.column_names(n)

    def generalized_force(self, q, qd, tau, coef):
        raise RobustDrakeError("presliding_friction has internal state: use its block "
                               "(PreslidingFrictionBlock) or columns on a trajectory")

    def block(self, n, parameters, **kw):
        return PreslidingFrictionBlock(self, n, self.coef_from_parameters(parameters, n))


def presliding_state(q, x0, z0=0.0):
    """Dahl state z along a sampled position path q (N,), exact per monotone step (pure)."""
    q = np.asarray(q, dtype=float)
    z = np.empty(len(q))
    zk = float(z0)
    if len(q):
        z[0] = zk
    dq = np.diff(q)
    s = np.sign(dq)
    a = np.exp(-np.abs(dq) / float(x0))
    for k in range(len(dq)):
        zk = s[k] + (zk - s[k]) * a[k]
        z[k + 1] = zk
    return z


class PreslidingFrictionBlock(LeafSystem):
    """Continuous-state Dahl friction (see :class:`PreslidingFriction`): state z (n; joints the
    effect does not act on stay at 0), input ``state`` (2n), output ``generalized_force`` =
    -F_d z (depends on the block's own state only: no direct feedthrough)."""

    def __init__(self, effect: "PreslidingFriction", n: int, coef):
        super().__init__()
        self.effect, self.n = effect, n
        self.x0 = float(effect.shape["presliding_displacement"])
        self.Fd = np.zeros(n)
        js = effect.joints(n)
        self.Fd[js] = np.asarray(coef, dtype=float).reshape(-1)  # one F_d per acting joint
        self.active = np.zeros(n)
        self.active[js] = 1.0
        self.set_name(f"effect_presliding_friction_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareContinuousState(n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.xc_ticket()})

    def DoCalcTimeDerivatives(self, context, derivatives):
        z = context.get_continuous_state_vector().CopyToVector()
        qd = self._state.Eval(context)[self.n:]
        derivatives.get_mutable_vector().SetFromVector(self.active * (qd - np.abs(qd) * z) / self.x0)

    def _calc(self, context, output):
        z = context.get_continuous_state_vector().CopyToVector()
        output.SetFromVector(-self.Fd * z)


# ---------------------------------------------------------------------------------------------
# Kinds for structure outside the original library (issue 13). They are offered to the selection
# only where a residual diagnostic (diagnostics.py) found their structure: their ``candidates``
# return nothing unless given ``diagnostics=[rows of diagnostics.diagnose]``.
# ---------------------------------------------------------------------------------------------
class TimeEffect(Effect):
    """Base of kinds whose columns depend on time t [s] (the log's clock: time since the run's
    t = 0, which is also the simulator's context time in the block)."""

    needs_time: ClassVar[bool] = True

    def _features_t(self, j, t, q, qd, tau):
        raise NotImplementedError

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None, t=None) -> np.ndarray:
        if t is None:
            raise RobustDrakeError(f"{self.kind} columns need the time stamps t")
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        t = np.broadcast_to(np.asarray(t, dtype=float).ravel(), (N,))
        cols = np.zeros((N, n, self.num_coef(n)))
        m = len(self.coef_names)
        for i, j in enumerate(self.joints(n)):
            cols[:, j, i * m:(i + 1) * m] = self._features_t(j, t, q, None if qd is None else np.atleast_2d(qd), tau)
        return cols

    def columns(self, data):
        cols = self.evaluate_columns(data.q, data.qd, None, data.tau, None, t=data.t)
        return cols, self.column_names(np.asarray(data.q).shape[1])

    def generalized_force(self, q, qd, tau, coef, t=0.0):
        """Block output for one state at time t [s]: -(columns @ coef), shape (n,)."""
        cols = self.evaluate_columns(np.atleast_2d(q), np.atleast_2d(qd), None, None, None, t=[t])
        return -(cols[0] @ np.asarray(coef, dtype=float))

    def block(self, n, parameters, **kw):
        return TimeEffectBlock(self, n, self.coef_from_parameters(parameters, n))


class TimeEffectBlock(LeafSystem):
    """Stateless block of a :class:`TimeEffect`: ``generalized_force = -(columns(state, t) @ coef)``
    with t the context time [s]."""

    def __init__(self, effect: TimeEffect, n: int, coef):
        super().__init__()
        self.effect, self.n = effect, n
        self.coef = np.asarray(coef, dtype=float).copy()
        self.set_name(f"effect_{effect.kind}_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc)

    def _calc(self, context, output):
        x = self._state.Eval(context)
        output.SetFromVector(self.effect.generalized_force(x[:self.n], x[self.n:], None, self.coef,
                                                           t=context.get_time()))


class PeriodicDisturbanceEffect(TimeEffect):
    """A torque periodic in *time* acting on joint j: a DISTURBANCE of the environment (a pump, a
    vibrating base, a neighbouring machine), not a property of the arm -- it does not depend on
    the state and is reported as a disturbance (``is_disturbance``).

    The plant receives f_e = A sin(2 pi f t + phi); columns [sin(2 pi f t), cos(2 pi f t)] with
    coefficients (a, b) = -A (cos phi, sin phi) (sign convention of this module: columns @ coef
    = -f_e). The frequency f [Hz] is a fixed shape parameter taken from the residual's spectrum
    (``diagnostics.periodic_peaks``, refined by a 1-D least-squares search), so the rest is linear.
    The phase is referenced to each log's t = 0: it predicts another log only if the disturbance
    keeps its phase relative to the logs' clocks (a synchronous source); otherwise use it on the
    fit data to clean the residual and report it, not to predict.
    Admissible: 2 / T_file <= f <= the analysis band's cut-off (below, it is a drift; above, the
    filter removed it); amplitude >= 0 by construction."""

    kind = "periodic_disturbance"
    coef_names = ("sin", "cos")
    default_shape = {"frequency": 1.0}
    is_disturbance = True
    bounds = {"frequency": (1e-12, math.inf)}

    def admissible(self, parameters, context=None):
        """frequency in the analysis band (2 / T_file, f_c): below it a drift, above it filtered
        out; amplitude <= the largest torque the joint carried."""
        parameters = {**self.shape, **parameters}
        why = check_bounds(parameters, self.bounds) or _limit_by(self, parameters, "amplitude", context,
                                                                 "tau_max", "max |tau|")
        if why or context is None or context.band_hz is None:
            return why
        lo, hi = context.band_hz
        return check_bounds(parameters, {"frequency": (lo, hi)})

    def _features_t(self, j, t, q, qd, tau):
        ph = 2.0 * math.pi * float(self.shape["frequency"]) * t
        return np.column_stack([np.sin(ph), np.cos(ph)])

    def _parameters_one(self, c):
        a, b = float(c[0]), float(c[1])
        return {"sin": a, "cos": b, "amplitude": math.hypot(a, b), "phase": math.atan2(-b, -a)}

    def _coef_one(self, p):
        if "amplitude" in p:
            A, phi = float(p["amplitude"]), float(p.get("phase", 0.0))
            return [-A * math.cos(phi), -A * math.sin(phi)]
        return [float(p["sin"]), float(p["cos"])]

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        return [cls(joint=d["joint"], frequency=round(float(d["frequency_hz"]), 5))
                for d in diagnostics or [] if d.get("test") == "periodic"]


class DeadZone(Effect):
    """Driver dead-zone on joint j: commanded torque below the threshold d [N m] in magnitude does
    not reach the joint; the joint receives tau - c clip(tau, -d, d) (c = 1: all of it is lost).

    Columns: clip(tau_j, -d, d) (the torque the motor spends without effect), coefficient
    ``share`` c (dimensionless); d is a fixed shape parameter per candidate, from the dead-band
    diagnostic (``diagnostics.dead_band``, candidates at 0.9, 1 and 1.1 times its estimate).
    Block input ``tau``: generalized_force = -c clip(tau_j, -d, d). Admissible: 0.5 <= c <= 1.5
    (``admissible``). Predicting the commanded torque from the motion needs the inverse
    dead-zone (:meth:`commanded_torque`), not a fixed-point iteration (the map has slope c ~ 1
    inside the band)."""

    kind = "dead_zone"
    coef_names = ("share",)
    needs_tau = True
    default_shape = {"threshold": 0.1}
    limits = {"share": (0.5, 1.5)}
    #: c ~ 1 for a dead-zone (the torque below d is lost); d > 0
    bounds = {"share": limits["share"], "threshold": (1e-12, math.inf)}

    def _features(self, j, q, qd, qdd, tau, taud):
        d = float(self.shape["threshold"])
        return np.clip(tau[:, j], -d, d)[:, None]

    def commanded_torque(self, m, coef):
        """Pure inverse of tau = m + c clip(tau, -d, d) for the joint's needed torque m [N m]:
        tau = m / (1 - c) where |m| <= (1 - c) d, else m + c d sign(m)."""
        m = np.asarray(m, dtype=float)
        c, d = float(np.ravel(coef)[0]), float(self.shape["threshold"])
        inside = np.abs(m) <= (1.0 - c) * d
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(inside, m / max(1.0 - c, 1e-12), m + c * d * np.sign(m))

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        return [cls(joint=d["joint"], threshold=round(float(d["threshold"]) * k, 6))
                for d in diagnostics or [] if d.get("test") == "dead_band" for k in (0.9, 1.0, 1.1)]


class FrictionDrift(TimeEffect):
    """Friction that changes slowly over a run (warming up): viscous and Coulomb coefficients
    linear in time, b(t) = b_0 + r_b t, F_c(t) = F_c0 + r_c t, with b_0, F_c0 the baseline's.

    Columns [t qd_j, t tanh(qd_j / v_eps)] with t the run's time [s]; coefficients
    ``viscous_rate`` r_b [N m s/rad per s] and ``coulomb_rate`` r_c [N m/s]. Either sign is
    physical (warming thins the lubricant: r_b < 0; a seal or a brake heating up: r_b > 0);
    admissible when the coefficients stay non-negative over the run given the baseline's
    (``admissible`` with ``baseline`` and ``duration``). Offered where ``diagnostics.friction_drift``
    fired."""

    kind = "friction_drift"
    coef_names = ("viscous_rate", "coulomb_rate")
    default_shape = {"v_eps": V_EPS}

    def admissible(self, parameters, context=None):
        """Viscous and Coulomb levels non-negative at the end of the run: b_0 + r_b T >= 0,
        F_c0 + r_c T >= 0 (b_0, F_c0 the same fit's, T ``context.duration``)."""
        if context is None or context.viscous is None or context.duration is None:
            return ""
        n = len(context.viscous)
        for key, rate in (("viscous", "viscous_rate"), ("coulomb", "coulomb_rate")):
            base = _joint_values(self, getattr(context, key), n)
            end = base + np.atleast_1d(np.asarray(parameters[rate], float)) * context.duration
            if np.any(end < 0):
                return f"{key} coefficient {np.round(end, 4).tolist()} < 0 at the end of the run"
        return ""

    def _features_t(self, j, t, q, qd, tau):
        v = qd[:, j]
        return np.column_stack([t * v, t * smooth_sign(v, self.shape["v_eps"])])

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        js = sorted({d["joint"] for d in diagnostics or [] if d.get("test") == "drift"})
        return [cls(joint=j) for j in js]


# ---------------------------------------------------------------------------------------------
# Torques that depend on other joints' angles (issue 21)
# ---------------------------------------------------------------------------------------------
#: term letter -> label; ``{k}`` is the joint NUMBER from 1 (``sin(q1)``: the first joint, as the
#: CSV column ``q1``); the parsed tuples (:func:`parse_terms`) hold 0-based indices
_TERM_LABELS = {"s": "sin(q{k})", "c": "cos(q{k})", "l": "q{k}", "p": "q{k}^2"}


def term_tokens(terms: list[tuple[str, int]]) -> str:
    """Parsed terms (0-based joint indices) as the token text (``"s1,c1"``, joints from 1)."""
    return ",".join(f"{f}{k + 1}" for f, k in terms)


def configuration_terms(n: int, joint: int, prismatic=()) -> list[str]:
    """The default basis of :class:`ConfigurationDependent` on ``joint`` (0-based index) of an
    n-joint arm, as tokens whose number is the joint NUMBER from 1 (``s1`` = sin of the first
    joint's angle, the CSV column ``q1``):
    for every other revolute joint k, ``s<k>`` = sin q_k and ``c<k>`` = cos q_k [1]; for a
    prismatic joint k, ``l<k>`` = q_k [m] and ``p<k>`` = q_k^2 [m^2] (its own prismatic joint:
    only ``p<j>``, q_j is the ``spring`` kind). Own revolute angle left out: sin q_j, cos q_j
    are the first harmonic of ``position_dependent`` and q_j is ``spring``; the constant is
    ``torque_offset``. At most 2 (n - 1) + 1 columns."""
    out = []
    for k in range(n):
        if k in prismatic:
            out += ([] if k == joint else [f"l{k + 1}"]) + [f"p{k + 1}"]
        elif k != joint:
            out += [f"s{k + 1}", f"c{k + 1}"]
    return out


def parse_terms(terms) -> list[tuple[str, int]]:
    """[(function letter, 0-based joint index)] of a term list ``"s1,c1,l3"`` (or a list of
    tokens) whose numbers are joint numbers from 1 (``s1`` = sin q1, the first joint)."""
    tokens = [t.strip() for t in (terms.split(",") if isinstance(terms, str) else terms) if str(t).strip()]
    out = []
    for t in tokens:
        f, k = t[:1], t[1:]
        if f not in _TERM_LABELS or not k.isdigit() or int(k) < 1:
            raise RobustDrakeError(f"configuration_dependent: bad term {t!r}: use s<k> (sin q_k), c<k> "
                                   "(cos q_k), l<k> (q_k) or p<k> (q_k^2), k a joint number from 1")
        out.append((f, int(k) - 1))
    if not out:
        raise RobustDrakeError("configuration_dependent: no terms")
    return out


def term_values(terms: list[tuple[str, int]], q) -> np.ndarray:
    """Pure: the basis functions phi_i(q) (N, m) of parsed ``terms`` at configurations q (N, n)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if max(k for _, k in terms) >= q.shape[1]:
        raise RobustDrakeError(f"configuration_dependent: a term names joint {max(k for _, k in terms) + 1} "
                               f"of a {q.shape[1]}-joint arm")
    fun = {"s": np.sin, "c": np.cos, "l": lambda x: x, "p": np.square}
    return np.stack([fun[f](q[:, k]) for f, k in terms], axis=1)


class ConfigurationDependent(Effect):
    """A torque on joint j that is a low-order function of the configuration: a cable or hose
    dragged by the other links, a spring coupled across joints, a counterbalance acting through
    another joint's linkage. Offered only where the baseline residual of joint j depends on
    another joint's angle (``residual.configuration_dependence``).

    Model (eq. CD1)::

        f_e,j(q) = -sum_i c_i phi_i(q),     phi in {sin q_k, cos q_k : k != j revolute}
                                                 + {q_k, q_k^2 : k prismatic}

    f_e the torque [N m] the effect adds to joint j (plant side), c_i [N m] (per m, m^2 on a
    prismatic joint) the coefficients of the columns phi_i(q) on joint j's equation; as
    everywhere in this module, ``columns @ c`` is the torque the motor supplies because of the
    effect. A first harmonic per joint is the lowest order that is periodic in a revolute
    angle (a cable's or spring's geometry repeats every turn); with the constant (the
    ``torque_offset`` kind) and j's own sin/cos (``position_dependent`` harmonic 1) and q_j
    (``spring``) left out it has 2 (n - 1) columns -- 4 on a 3-joint arm, 12 on a 7-joint one;
    products q_k q_l would give n^2 columns for the few hundred independent samples of a log.

    Shape ``terms``: the basis as tokens numbered from 1 like the joints in every label
    (``"s1,c1,s2,c2"``: sin q1, cos q1, ... of the first two joints); None is
    :func:`configuration_terms` of the arm. ``joint=None`` (the excitation designer's
    ``--for-effects``): the default basis on every joint, separate coefficients ``"j<j>:sin(q1)"`` (j the joint number from 1).
    :meth:`candidates` drops every term that lies in the
    span of the rigid-body gravity columns of joint j (:func:`gravity_aliases`), so the
    candidate never duplicates gravity: on a serial arm joint j's gravity torque depends on its
    own angle in every term (the first joint of a vertical-plane arm: a sin q_0 + b cos q_0 +
    ...), so single other-joint terms are rarely aliases, but a linkage (parallelogram,
    counterbalance) can make joint j's gravity a function of another joint's angle alone. What
    is not an exact alias but nearly collinear on the data is rejected by the fit's
    identifiability check (``selection._trial``).

    Parameters (:meth:`parameters`): each coefficient by its term (``"sin(q1)"``: c [N m]),
    ``terms``, and over the configurations of the data the columns were first built on (the fit
    data in the repair) ``explained_rms`` = RMS_t |f_e,j(q(t))| and ``peak`` = max_t |f_e,j|
    [N m]. Admissible: the peak over the data within the joint's torque range (max |tau_j|).
    Block: :class:`ConfigurationDependentBlock`."""

    kind = "configuration_dependent"
    default_shape = {"terms": None}

    def __init__(self, joint: int | None = None, **shape):
        super().__init__(joint, **shape)
        if self.shape["terms"] is not None:
            if self.joint is None:
                raise RobustDrakeError("configuration_dependent: terms need a joint (joint=None takes the "
                                       "default basis on every joint)")
            self.shape["terms"] = term_tokens(parse_terms(self.shape["terms"]))
            if any(f in "sc" and k == self.joint for f, k in parse_terms(self.shape["terms"])):
                raise RobustDrakeError("configuration_dependent: sin / cos of the joint's own angle are the "
                                       "position_dependent kind (harmonic 1), not a term of this one")
        self.reference_q = None  # configurations of the first data the columns were built on

    def terms(self, n: int) -> list[tuple[str, int]]:
        """The parsed basis of the effect's joint (joint given)."""
        t = self.shape["terms"]
        return parse_terms(t) if t is not None else parse_terms(configuration_terms(n, self.joint))

    def layout(self, n: int) -> list[tuple[int, list[tuple[str, int]]]]:
        """[(joint, parsed terms)]: one entry, or with joint=None the default basis of every joint
        (separate coefficients per joint, as the library's per-joint kinds)."""
        if self.joint is None:
            return [(j, parse_terms(configuration_terms(n, j))) for j in range(n)] if n > 1 else []
        self.joints(n)
        return [(self.joint, self.terms(n))]

    def term_labels(self, n: int) -> list[str]:
        """Coefficient names: the term's label (``"sin(q1)"``), ``"j<j>:"`` (from 1) before it with joint=None."""
        pre = (lambda j: f"j{j + 1}:") if self.joint is None else (lambda j: "")
        return [pre(j) + _TERM_LABELS[f].format(k=k + 1) for j, ts in self.layout(n) for f, k in ts]

    def num_coef(self, n: int) -> int:
        return sum(len(ts) for _, ts in self.layout(n))

    def column_names(self, n: int) -> list[str]:
        labels = iter(self.term_labels(n))
        return [f"{self.kind}[{j + 1}]:{next(labels).split(':')[-1]}" for j, ts in self.layout(n) for _ in ts]

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None) -> np.ndarray:
        """(N, n, m) columns: phi(q) (eq. CD1) on joint j's rows, zero elsewhere."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        cols = np.zeros((N, n, self.num_coef(n)))
        i = 0
        for j, ts in self.layout(n):
            cols[:, j, i:i + len(ts)] = term_values(ts, q)
            i += len(ts)
        return cols

    def columns(self, data):
        if self.reference_q is None:
            self.reference_q = subsample_configurations(data.q)
        return super().columns(data)

    def _n_from(self, coef) -> int:
        if self.shape["terms"] is not None:
            return max([k for _, k in self.terms(0)] + [self.joint]) + 1
        m = len(coef)  # default basis: 2 (n - 1) terms per joint (all n joints with joint=None)
        return m // 2 + 1 if self.joint is not None else int(round((1 + math.sqrt(1 + 2 * m)) / 2))

    def torque(self, coef, q) -> np.ndarray:
        """Pure: the plant-side torque f_e(q) (N, n) [N m] at configurations q (N, n) (eq. CD1)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return -(self.evaluate_columns(q) @ np.asarray(coef, dtype=float))

    def parameters(self, coef, q=None) -> dict:
        """Coefficients by term, ``terms``, and ``explained_rms`` / ``peak`` [N m] over ``q``
        (default: :attr:`reference_q`, the data the columns were first built on)."""
        coef = np.asarray(coef, dtype=float).ravel()
        n = self._n_from(coef) if q is None else np.atleast_2d(q).shape[1]
        labels = self.term_labels(n)
        if len(coef) != len(labels):
            raise RobustDrakeError(f"{self.name}: expected {len(labels)} coefficients, got {len(coef)}")
        out = {lab: float(c) for lab, c in zip(labels, coef)}
        if self.joint is not None:
            out["terms"] = term_tokens(self.terms(n))
        q = self.reference_q if q is None else q
        if q is not None and np.atleast_2d(q).shape[1] == n:
            f = self.torque(coef, q)[:, [j for j, _ in self.layout(n)]]
            rms, peak = np.sqrt(np.mean(f**2, axis=0)), np.max(np.abs(f), axis=0)
            one = self.joint is not None
            out.update(explained_rms=float(rms[0]) if one else rms.tolist(),
                       peak=float(peak[0]) if one else peak.tolist())
        return out

    def coef_from_parameters(self, parameters: dict, n: int) -> np.ndarray:
        missing = [lab for lab in self.term_labels(n) if lab not in parameters]
        if missing:
            raise RobustDrakeError(f"{self.name}: parameters lack {missing}")
        return np.asarray([float(parameters[lab]) for lab in self.term_labels(n)])

    def admissible(self, parameters, context=None):
        """The peak of f_e,j over the data's configurations (``context.configurations``) <= max
        |tau_j| the joint carried (every acting joint)."""
        if context is None or context.tau_max is None or context.configurations is None:
            return ""
        q = context.configurations
        js = [j for j, _ in self.layout(q.shape[1])]
        peak = np.max(np.abs(self.torque(self.coef_from_parameters(parameters, q.shape[1]), q)[:, js]), axis=0)
        lim = np.asarray(context.tau_max, float)[js]
        if np.all(peak <= lim + 1e-12):
            return ""
        return f"peak torque {np.round(peak, 4).tolist()} N m above max |tau| {np.round(lim, 4).tolist()} N m"

    def block(self, n, parameters, **kw):
        return ConfigurationDependentBlock(self, n, self.coef_from_parameters(parameters, n))

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, robot=None, **context):
        """One candidate per joint where ``residual.configuration_dependence`` fired (rows
        ``test == "configuration_dependence"`` in ``diagnostics``), its basis without the terms in
        the span of that joint's gravity columns (``robot`` given: :func:`gravity_aliases`)."""
        joints = sorted({d["joint"] for d in diagnostics or [] if d.get("test") == "configuration_dependence"})
        prismatic, reg = _joint_kinds(robot, n_joints) if joints else ((), None)
        out = []
        for j in joints:
            terms = configuration_terms(n_joints, j, prismatic)
            if reg is not None:
                drop = set(gravity_aliases(reg, j, terms))
                terms = [t for t in terms if t not in drop]
            if terms:
                out.append(cls(joint=j, terms=",".join(terms)))
        return out


def _joint_kinds(robot, n: int):
    """(prismatic joint indices, regressor) of ``robot`` (((), None) without a robot)."""
    if robot is None:
        return (), None
    from robust_drake.identification.least_squares import load_regressor

    reg = load_regressor(robot)
    joints = [reg.plant.get_joint(ji) for ji in reg.plant.GetJointIndices()
              if reg.plant.get_joint(ji).num_velocities() == 1]
    prismatic = tuple(jt.velocity_start() for jt in joints if "prismatic" in jt.type_name())
    return prismatic, (reg if reg.n == n else None)


def gravity_aliases(regressor, joint: int, terms, samples: int = 256, seed: int = 0) -> list[str]:
    """Terms of ``terms`` (tokens) that lie in the span of the rigid-body gravity columns of
    ``joint`` (and of the terms kept before them): Y_j(q, 0, 0) of the base regressor at
    ``samples`` random configurations (revolute angles uniform in [-pi, pi], prismatic positions
    in their limits or [-1, 1] m); a term whose least-squares residual on those columns is below
    ``least_squares.RANK_TOL`` of its norm is an identity of the model (noise free), not a fit."""
    from robust_drake.identification.least_squares import RANK_TOL

    n = regressor.n
    rng = np.random.default_rng(seed)
    prismatic = {k for f, k in parse_terms(terms) if f in "lp"}
    Q = rng.uniform(-math.pi, math.pi, (samples, n))
    for k in prismatic:
        jt = [regressor.plant.get_joint(ji) for ji in regressor.plant.GetJointIndices()
              if regressor.plant.get_joint(ji).num_velocities() == 1][k]
        lo, hi = float(jt.position_lower_limits()[0]), float(jt.position_upper_limits()[0])
        lo, hi = (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else (-1.0, 1.0)
        Q[:, k] = rng.uniform(lo, hi, samples)
    zero = np.zeros_like(Q)
    span = np.asarray(regressor.evaluate(Q, zero, zero), float)[:, joint, :]
    span = span[:, np.linalg.norm(span, axis=0) > 0]
    drop = []
    for tok in (terms.split(",") if isinstance(terms, str) else terms):
        phi = term_values(parse_terms([tok]), Q)
        if span.shape[1]:
            resid = phi - span @ np.linalg.lstsq(span, phi, rcond=None)[0]
        else:
            resid = phi
        if np.linalg.norm(resid) <= RANK_TOL * np.linalg.norm(phi):
            drop.append(tok)
        else:
            span = np.hstack([span, phi])
    return drop


class ConfigurationDependentBlock(LeafSystem):
    """Stateless block of :class:`ConfigurationDependent`: input ``state`` (2n), output
    ``generalized_force`` (n), zero except on the acting joint(s) j: -sum_i c_i phi_i(q) [N m]
    (eq. CD1).
    Its output depends on the state input only (no time, no torque)."""

    def __init__(self, effect: ConfigurationDependent, n: int, coef):
        super().__init__()
        self.n = n
        self.coef = np.asarray(coef, dtype=float).copy()
        if len(self.coef) != effect.num_coef(n):
            raise RobustDrakeError(f"{effect.name}: {effect.num_coef(n)} coefficients expected, got {len(self.coef)}")
        fun = {"s": math.sin, "c": math.cos, "l": float, "p": lambda x: x * x}
        terms = [(j, fun[f], k) for j, ts in effect.layout(n) for f, k in ts]
        self._fun = [(j, f, k, float(c)) for (j, f, k), c in zip(terms, self.coef)]
        self.set_name(f"effect_{effect.kind}_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.input_port_ticket(self._state.get_index())})

    def _calc(self, context, output):
        x = self._state.Eval(context)
        out = np.zeros(self.n)
        for j, f, k, c in self._fun:
            out[j] -= c * f(float(x[k]))
        output.SetFromVector(out)


def admissible(effect, parameters: dict, baseline: dict | None = None, duration: float | None = None,
               band_hz: tuple | None = None) -> str:
    """Compatibility wrapper of :meth:`Effect.admissible` for one joint's fit: ``baseline`` =
    {"viscous": b_0, "coulomb": F_c0} of the effect's joint, ``duration`` T [s], ``band_hz``."""
    ctx = None
    if baseline is not None or duration is not None or band_hz is not None:
        n = (effect.joint or 0) + 1
        pad = lambda v: None if v is None else tuple([float(v)] * n)  # noqa: E731
        ctx = PhysicalContext(coulomb=pad(None if baseline is None else baseline["coulomb"]),
                              viscous=pad(None if baseline is None else baseline["viscous"]),
                              duration=duration, band_hz=band_hz)
    return effect.admissible(parameters, ctx)


# ---------------------------------------------------------------------------------------------
EFFECTS: dict[str, type[Effect]] = {
    cls.kind: cls for cls in (Stribeck, SmoothCoulomb, AsymmetricCoulomb, LoadDependentFriction,
                              PositionDependent, TorqueOffset, TorqueScale, RotorInertia, Spring,
                              TimeDelay, Payload, PreslidingFriction,
                              PeriodicDisturbanceEffect, DeadZone, FrictionDrift, ConfigurationDependent)
}

#: kinds offered only where a residual diagnostic found their structure (``candidates`` needs
#: ``diagnostics=``); they have no entry in ``simulated.HIDDEN_CASES`` but cases in
#: ``simulated_cases.OUTSIDE_CASES`` (``configuration_dependent``: the PUMA cable of
#: tests/test_configuration_dependent.py, offered by ``residual.configuration_dependence``)
DIAGNOSTIC_KINDS = ("periodic_disturbance", "dead_zone", "friction_drift", "configuration_dependent")


def make_effect(kind: str, joint: int | None = None, **shape) -> Effect:
    """An effect instance by kind name (RobustDrakeError listing the kinds if unknown); ``joint``
    is the 0-based joint index (``make_effect("spring", 1).name == "spring[2]"``)."""
    try:
        cls = EFFECTS[kind]
    except KeyError:
        raise RobustDrakeError(f"unknown effect kind {kind!r}; known: {', '.join(EFFECTS)}") from None
    return cls(joint=joint, **shape)


def all_candidates(n_joints: int, kinds=None, **context) -> list[Effect]:
    """Every candidate instance of the given kinds (default all) for an n-joint arm."""
    out = []
    for k in kinds or EFFECTS:
        out.extend(EFFECTS[k].candidates(n_joints, **context))
    return out


# ---------------------------------------------------------------------------------------------
# Diagram helpers (used by the experiment generator and by replay)
# ---------------------------------------------------------------------------------------------
def effect_force_blocks(effects, n, sample_period=None) -> list:
    """The force blocks of ``effects`` = [(Effect, parameters), ...] for an n-joint plant, in
    order (plant-modifying effects have none)."""
    blocks = [eff.block(n, params, sample_period=sample_period) for eff, params in effects]
    return [b for b in blocks if b is not None]


def add_effect_blocks(builder, plant, tau_port, effects, sample_period=None, extra_blocks=()):
    """Connect ``tau_port`` (commanded torque, n) plus every force-type effect block (then the
    already built ``extra_blocks``) into the plant's ``applied_generalized_force`` input through
    :func:`robust_drake.systems.forces.sum_into_plant`. ``effects`` = [(Effect, parameters),
    ...]; plant-modifying effects must already have been applied (``load_plant(robot,
    effects)``). Returns the list of added blocks."""
    from robust_drake.systems.forces import add_force_blocks, sum_into_plant

    blocks = effect_force_blocks(effects, plant.num_velocities(), sample_period) + list(extra_blocks)
    ports = add_force_blocks(builder, plant, blocks, tau_port)
    sum_into_plant(builder, plant, [tau_port] + ports, name="applied_force_sum")
    return blocks


def closed_loop_hooks(effects, sample_period=None) -> dict:
    """Hooks for :class:`robust_drake.diagram.ClosedLoopConfig`: ``{"effects": [...],
    "plant_setup": [...]}`` from ``[(Effect, parameters), ...]``. Force-type effects become block
    factories ``f(ctx)`` (the delay line samples at the loop's period unless ``sample_period``);
    plant-modifying ones become ``f(plant, context)`` calls of :meth:`Effect.apply_to_context`.
    Usage: ``ClosedLoopConfig(..., **closed_loop_hooks(chosen))``."""
    blocks, setup = [], []
    for eff, params in effects:
        if eff.modifies_plant:
            setup.append(lambda plant, ctx, e=eff, p=params: e.apply_to_context(plant, ctx, p))
        else:
            blocks.append(lambda bctx, e=eff, p=params: e.block(
                bctx.n, p, sample_period=sample_period or bctx.period))
    return {"effects": blocks, "plant_setup": setup}
