"""The effect contract: the :class:`Effect` base class, its force block and the helpers every kind
shares (smooth sign, bounds, the physical context a fit is judged in).

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
    #: with ``needs_tau``: joint j's features read the torque of joint j only (``tau[:, j]``), so
    #: an output-error prediction of joint j needs no other joint's (``fitting.predict_tau``'s
    #: ``joints``). False (the safe default for a user's kind): every joint is predicted.
    own_joint_tau: ClassVar[bool] = False
    needs_qdd: ClassVar[bool] = False  # the columns use acceleration
    modifies_plant: ClassVar[bool] = False  # realised by apply_to_plant, block() is None
    shared: ClassVar[bool] = False  # joint=None -> one coefficient shared by all joints
    #: the kind claims a shape of friction against velocity: kept only if it explains the rows
    #: away from that joint's velocity reversals (model_repair.stages.validated_gain_guard)
    velocity_shape: ClassVar[bool] = False
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
