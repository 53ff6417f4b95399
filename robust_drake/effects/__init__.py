"""Library of candidate effects: each one is both extra regressor columns and a Drake block.

One module per idea: :mod:`.base` (the :class:`Effect` contract, its sign convention and shared
helpers), :mod:`.friction`, :mod:`.position` (q-dependent torques), :mod:`.sensor` (offset,
gain, delay of the torque channel), :mod:`.plant` (rotor inertia, payload: they change the plant),
:mod:`.diagnosed` (kinds offered after a residual diagnostic), :mod:`.kinds` (the registry
:data:`EFFECTS`) and :mod:`.blocks` (diagram helpers for ``[(Effect, parameters), ...]``).
Every name is handed on here: ``from robust_drake.effects import make_effect``.
"""

from robust_drake.effects.base import (CONTEXT_CONFIGURATIONS, DEFAULT_BUS_DELAY, V_EPS, Effect, EffectForceBlock,
                                       PhysicalContext, admissible, check_bounds, delay_bound, smooth_sign,
                                       subsample_configurations, time_derivative)
from robust_drake.effects.blocks import add_effect_blocks, block_factory, effect_force_blocks, effect_hooks
from robust_drake.effects.diagnosed import (DeadZone, FrictionDrift, PeriodicDisturbanceEffect, TimeEffect,
                                            TimeEffectBlock)
from robust_drake.effects.friction import (AsymmetricCoulomb, LoadDependentFriction, PreslidingFriction,
                                           PreslidingFrictionBlock, SmoothCoulomb, Stribeck, presliding_state)
from robust_drake.effects.kinds import DIAGNOSTIC_KINDS, EFFECTS, all_candidates, make_effect
from robust_drake.effects.plant import Payload, RotorInertia, load_plant, resolve_robot_path
from robust_drake.effects.position import (ConfigurationDependent, ConfigurationDependentBlock, PositionDependent,
                                           Spring, configuration_terms, gravity_aliases, parse_terms, term_tokens,
                                           term_values)
from robust_drake.effects.sensor import TimeDelay, TorqueDelayLine, TorqueOffset, TorqueScale, equivalent_gain_error
