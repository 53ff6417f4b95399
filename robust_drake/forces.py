"""The one force path into the plant: torque sources summed into ``applied_generalized_force``.

Every diagram that drives a ``MultibodyPlant`` (the closed loop of :mod:`robust_drake.diagram`,
the replay of :mod:`robust_drake.model_repair.replay`, the simulated experiment of
:mod:`robust_drake.synthetic.simulated`) builds its plant-side forces with these two
functions::

    tau ------------------------------------------------+
    plant.state --> force block (state[, tau]) --gf-----+--> Adder --> plant.applied_generalized_force

A force block is any LeafSystem with input ``state`` (2n, the plant's [q, v]), optionally input
``tau`` (n, the commanded torque) and output ``generalized_force`` (n) [N m or N]: friction
(:class:`robust_drake.systems.friction.CoulombViscousFriction`), the effect blocks of
:mod:`robust_drake.effects`, user blocks.  The Adder sums its inputs in the order
given (tau first), so a diagram's applied force does not depend on which builder made it.
"""

from __future__ import annotations

__all__ = ["add_force_blocks", "sum_into_plant"]


def add_force_blocks(builder, plant, blocks, tau=None) -> list:
    """Add every block to ``builder``, feed it the plant's state (and ``tau`` where it has a
    ``tau`` input); return their ``generalized_force`` output ports in the same order."""
    out = []
    for block in blocks:
        builder.AddSystem(block)
        builder.Connect(plant.get_state_output_port(), block.GetInputPort("state"))
        if block.HasInputPort("tau"):
            if tau is None:
                raise ValueError(f"force block {block.get_name()!r} needs a tau input and none was given")
            builder.Connect(tau, block.GetInputPort("tau"))
        out.append(block.GetOutputPort("generalized_force"))
    return out


def sum_into_plant(builder, plant, sources, name: str = "force_sum"):
    """Connect sum(``sources``) (OutputPorts of size n = plant.num_velocities()) to the plant's
    ``applied_generalized_force`` input.  One source is connected directly (returns None);
    several go through one ``Adder`` (returned) summing them in the given order."""
    from pydrake.systems.primitives import Adder

    sources = list(sources)
    if not sources:
        raise ValueError("sum_into_plant needs at least one force source")
    target = plant.get_applied_generalized_force_input_port()
    if len(sources) == 1:
        builder.Connect(sources[0], target)
        return None
    adder = builder.AddSystem(Adder(len(sources), plant.num_velocities()))
    adder.set_name(name)
    for i, port in enumerate(sources):
        builder.Connect(port, adder.get_input_port(i))
    builder.Connect(adder.get_output_port(0), target)
    return adder
