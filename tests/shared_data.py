"""Where the tests find the real measurements: ``$ROBUST_DRAKE_DATA`` or ``../shared/data`` beside
the repository (the layout CI uses)."""

import os


def dfki_root():
    """Folder holding ``design_A0``/``design_C1`` of the DFKI double pendulum, or None."""
    here = os.path.dirname(os.path.abspath(__file__))
    for root in (os.environ.get("ROBUST_DRAKE_DATA"), os.path.join(here, "..", "..", "shared", "data")):
        if root and os.path.isdir(os.path.join(root, "dfki_double_pendulum", "design_C1")):
            return os.path.join(root, "dfki_double_pendulum")
    return None
