"""robust_drake: robust identification and robust control of robot manipulators, on Drake.

Papers (text in ``../shared/seeds``):
- Calafiore & Indri, *Robust Calibration and Control of Robotic Manipulators*;
- Jaritz & Spong, *An Experimental Comparison of Robust Control Algorithms on a
  Direct Drive Manipulator*;
- Bascetta & Rocco, *Revising the robust control design for rigid robot manipulators*.
"""

from robust_drake.errors import RobustDrakeError

__all__ = ["RobustDrakeError"]
__version__ = "0.1.0"
