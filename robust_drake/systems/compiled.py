"""Stateless laws y = f(u) evaluated by Drake in C++ (``SymbolicVectorSystem``) behind named ports.

A Python output port costs a few microseconds per evaluation, and a plant-side force block is
evaluated at every integrator stage (BUILD_NOTES "Speed of the 2500 Hz loop").  Drake's ``SymbolicVectorSystem``
evaluates an expression tree in C++, but a stateless one aborts inside a diagram with continuous
state (``DoCalcTimeDerivatives(): condition 'dynamics_.size() > 0' failed``, pydrake 1.51): the
block here carries one dummy continuous state z with z' = 0, which the law does not read.

:class:`SymbolicBlock` is a small Diagram exporting that system's ports under the names a
LeafSystem of the project would have (e.g. ``state`` -> ``generalized_force``), so it is wired,
named and replaced like any other block.  The Python reference of every law built this way is
kept beside it and tested equal (tests/test_compiled_blocks.py).

What a block costs per 2500 Hz tick of the D2R2 loop (callgrind instructions inside
``Simulator.AdvanceTo``, pydrake 1.51; the plant alone is 95.5k): every extra leaf system about
2.2-2.5k (a PassThrough or a ConstantVectorSource added beside the plant: Drake's time and state
change notifications, event collections and next-update-time queries visit every context), and
the Diagram around a single leaf that gives it named ports another 4.2-4.4k (its DiagramContext and
exported ports); the dummy state's derivative here about 1.9k per evaluation (two per RK2 step).
"""

from __future__ import annotations

from pydrake.symbolic import Variable
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import SymbolicVectorSystem


class SymbolicBlock(Diagram):
    """``output = exprs(input)`` in C++: one input port ``input_name`` (the variables ``u``, a
    sequence of pydrake symbolic Variables) and one output port ``output_name`` (``exprs``)."""

    def __init__(self, u, exprs, input_name: str, output_name: str, name: str):
        super().__init__()
        z = Variable("dummy_state")
        b = DiagramBuilder()
        self.symbolic = b.AddSystem(SymbolicVectorSystem(state=[z], input=list(u), dynamics=[0.0 * z],
                                                         output=list(exprs)))
        self.symbolic.set_name(f"{name}_expressions")
        b.ExportInput(self.symbolic.get_input_port(0), input_name)
        b.ExportOutput(self.symbolic.get_output_port(0), output_name)
        b.BuildInto(self)
        self.set_name(name)
