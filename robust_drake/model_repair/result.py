"""What :func:`robust_drake.repair` returns: the report as a typed, read-only result.

:class:`RepairResult` is a read-only mapping over the report dictionary (``report.json``), so
``res["verdict"]``, ``res["final"]["rms_validate"]``, ``dict(res)`` and ``json.dumps(res.report)``
work as they did on the plain dict; it adds the identified models (``model``, ``baseline_model``:
:class:`~robust_drake.identification.model.IdentifiedModel`), ``plot()`` and ``to_markdown()``.
"""

from __future__ import annotations

from collections.abc import Mapping


class RepairResult(Mapping):
    """A repair's outcome, a read-only mapping over its report.

    Parameters
    ----------
    report : dict
        The dictionary of ``report.json`` (the same object the pipeline built).
    out : str, optional
        The folder the report was written to (None: not written).
    """

    def __init__(self, report: dict, out: str | None = None):
        self._report = report
        self.out = out
        self._models: dict = {}

    @property
    def report(self) -> dict:
        """The report dictionary (``report.json``'s content)."""
        return self._report

    def __getitem__(self, key):
        return self._report[key]

    def __iter__(self):
        return iter(self._report)

    def __len__(self) -> int:
        return len(self._report)

    def _model(self, stage: str):
        if stage not in self._models:
            from robust_drake.identification.model import IdentifiedModel

            self._models[stage] = IdentifiedModel.from_report(self._report, stage)
        return self._models[stage]

    @property
    def model(self):
        """The repaired model (rigid body + friction + kept effects, the chosen estimator)."""
        return self._model("final")

    @property
    def baseline_model(self):
        """The baseline (rigid body + Coulomb + viscous, least squares)."""
        return self._model("baseline")

    def plot(self):
        """RMS torque residual per joint, baseline vs repaired (``plotting.repair_figure``)."""
        from robust_drake.plotting import repair_figure

        return repair_figure(self._report)

    def to_markdown(self) -> str:
        """``report.md``'s text, rendered from the same dictionary (``report.render_markdown``)."""
        from robust_drake.model_repair.report import render_markdown

        return render_markdown(self._report)

    def __repr__(self) -> str:
        fin = self._report.get("final") or {}
        kinds = [e.get("kind") for e in self._report.get("effects") or []]
        val = [round(x, 4) if isinstance(x, float) else x for x in fin.get("rms_validate") or []]
        return (f"RepairResult({self._report.get('robot')!r}: {self._report.get('verdict')}, effects {kinds}, "
                f"validation RMS {val} N m{', out=' + repr(self.out) if self.out else ''})")
