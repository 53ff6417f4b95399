"""Diagram helpers for a plain list of effects ``[(Effect, parameters), ...]``: their force blocks
summed into a plant (used by the experiment generator and by replay) and the plant side of a
closed loop (:func:`effect_hooks`).
"""

from __future__ import annotations


def effect_force_blocks(effects, n, sample_period=None) -> list:
    """The force blocks of ``effects`` = [(Effect, parameters), ...] for an n-joint plant, in
    order (plant-modifying effects have none)."""
    blocks = [eff.block(n, params, sample_period=sample_period) for eff, params in effects]
    return [b for b in blocks if b is not None]


def add_effect_blocks(builder, plant, tau_port, effects, sample_period=None, extra_blocks=()):
    """Connect ``tau_port`` (commanded torque, n) plus every force-type effect block (then the
    already built ``extra_blocks``) into the plant's ``applied_generalized_force`` input through
    :func:`robust_drake.forces.sum_into_plant`. ``effects`` = [(Effect, parameters),
    ...]; plant-modifying effects must already have been applied (``load_plant(robot,
    effects)``). Returns the list of added blocks."""
    from robust_drake.forces import add_force_blocks, sum_into_plant

    blocks = effect_force_blocks(effects, plant.num_velocities(), sample_period) + list(extra_blocks)
    ports = add_force_blocks(builder, plant, blocks, tau_port)
    sum_into_plant(builder, plant, [tau_port] + ports, name="applied_force_sum")
    return blocks


#: sample period [s] of a delay line whose loop context names none (a bare ``ctx`` with ``n`` only)
DEFAULT_SAMPLE_PERIOD = 1e-3


def block_factory(eff, parameters: dict, sample_period=None):
    """``f(ctx) -> LeafSystem``: the block of ``eff`` for the loop's ``ctx.n`` joints, built when
    the closed-loop builder asks for it. A delay line samples at ``sample_period`` [s] (None: the
    loop's ``ctx.period``, else :data:`DEFAULT_SAMPLE_PERIOD`)."""
    return lambda ctx: eff.block(ctx.n, parameters,
                                 sample_period=sample_period or getattr(ctx, "period", DEFAULT_SAMPLE_PERIOD))


def effect_hooks(effects, sample_period=None) -> dict:
    """The plant side of :class:`robust_drake.diagram.ClosedLoopConfig` for ``[(Effect,
    parameters), ...]``: ``{"effects": [...], "plant_setup": [...]}``. Force-type effects become
    block factories (:func:`block_factory`); plant-modifying ones become ``f(plant, context)``
    calls of :meth:`Effect.apply_to_context`, so none is dropped. Usage:
    ``ClosedLoopConfig(..., **effect_hooks(chosen))``; an identified model's whole loop is
    :meth:`IdentifiedModel.closed_loop_hooks`, which calls this for its plant."""
    blocks, setup = [], []
    for eff, params in effects:
        if eff.modifies_plant:
            setup.append(lambda plant, ctx, e=eff, p=params: e.apply_to_context(plant, ctx, p))
        else:
            blocks.append(block_factory(eff, params, sample_period))
    return {"effects": blocks, "plant_setup": setup}
