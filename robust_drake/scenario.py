"""Scenarios: small, serialisable descriptions of one closed loop, and batch specs.

A :class:`Scenario` holds plain data only (strings, numbers, lists, dicts), so it pickles to
worker processes and Dask workers and hashes to a stable id. ``Scenario.to_config()`` turns it
into a :class:`robust_drake.diagram.ClosedLoopConfig`.

A batch spec is a YAML or CSV file:

* YAML, product form: scalar defaults plus list-valued keys among ``robot``, ``trajectory``,
  ``controllers``, ``loads``, ``rates``, ``observers``, ``friction_compensation``, ``seeds``,
  expanded to every combination::

      robot: d2r2
      trajectory: cpt
      duration: 0.5
      controllers: [pd, sp1, {name: sp2, params: {epsilon: [0.05, 0.05]}, label: sp2-tight}]
      loads: [none, max]
      rates: [2500, 1000]
      seeds: [0, 1]

  ``controllers`` may also be a mapping ``{sp1: {params...}, sp2: {}}``; per-controller
  parameters can be given separately in ``controller_params: {sp1: {...}}``.
* YAML, list form: ``scenarios: [{controller: sp1, load: max}, ...]``, each entry merged over
  the scalar defaults of the file.
* CSV: one row per scenario, columns named like the :class:`Scenario` fields; dict-valued
  fields as JSON text, or spread over dotted columns (``controller_params.epsilon``).

Names (robots, loads, controllers, observers, trajectories) are checked against
:mod:`robust_drake.models` and :mod:`robust_drake.registry` before anything runs, so a typo
fails in a second rather than after an hour of simulations.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import os
import pathlib
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Iterable

from robust_drake.errors import RobustDrakeError
from robust_drake.loop_defaults import LOOP_DEFAULTS, robot_rate

__all__ = [
    "Scenario",
    "PRODUCT_KEYS",
    "expand_product",
    "load_spec",
    "scenarios_from_records",
    "spec_fingerprint",
    "validate_scenarios",
]

def _copy(v):
    """A copy of plain data (dicts and lists are copied one level deep)."""
    return dict(v) if isinstance(v, dict) else list(v) if isinstance(v, (list, tuple)) else v


def _floats_or_none(v):
    return None if v is None else [float(x) for x in v]


def _float_or_none(v):
    return None if v is None else float(v)


#: Conversions of Scenario fields copied to ClosedLoopConfig (plain data -> the config's types).
_TO_CONFIG = {"rate": float, "duration": _float_or_none, "true_theta": _floats_or_none,
              "friction_compensation": bool}
#: Scenario fields named like a ClosedLoopConfig field that are not copied (the seed goes on
#: only when the config has one, below).
_NOT_COPIED = {"seed"}
#: Conversions of ``extra`` entries: serialisable forms of ClosedLoopConfig fields.
_EXTRA_TO_CONFIG = {"effects": lambda v: [tuple(e) for e in v],
                    "plant_setup": lambda v: [_plant_setup_callable(e) for e in v]}


@dataclass
class Scenario:
    """One closed loop, as plain data: overrides of :class:`robust_drake.diagram.ClosedLoopConfig`
    (same defaults, :data:`robust_drake.loop_defaults.LOOP_DEFAULTS`; ``rate`` None = the robot
    description's, as the config's).

    ``friction`` switches the plant's Coulomb + viscous friction on (the robot's default
    values) or off; ``extra`` passes further :class:`ClosedLoopConfig` fields (``torque_limit``,
    ``encoder_resolution``, ``initial_q``, ``metrics_skip``, ``plant_friction`` values,
    ``effects`` as ``[name, params]`` pairs...). ``true_theta`` is the "true" plant parameter
    vector (JS eq. 14 for the D2R2) when it differs from the controller's nominal one.
    ``seed`` is recorded and passed on to the loop (``extra.seed``-aware blocks); ``draw`` and
    ``tags`` label Monte Carlo draws and user groupings, and take part in the id.
    ``label`` is a display name only (not part of the id).
    """

    robot: str = LOOP_DEFAULTS["robot"]
    load: str = LOOP_DEFAULTS["load"]
    controller: str = LOOP_DEFAULTS["controller"]
    controller_params: dict = field(default_factory=dict)
    trajectory: str = LOOP_DEFAULTS["trajectory"]
    trajectory_params: dict = field(default_factory=dict)
    rate: float | None = None  # None: the robot description's (ClosedLoopConfig's default)
    observer: str = LOOP_DEFAULTS["observer"]
    observer_params: dict = field(default_factory=dict)
    friction: bool = True
    friction_compensation: bool = LOOP_DEFAULTS["friction_compensation"]
    seed: int = 0
    duration: float | None = LOOP_DEFAULTS["duration"]
    true_theta: list | None = LOOP_DEFAULTS["true_theta"]
    draw: int | None = None
    tags: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    label: str | None = None

    def __post_init__(self):
        if self.rate is None:  # the rate ClosedLoopConfig takes for this robot (its description's)
            try:
                self.rate = robot_rate(self.robot)
            except RobustDrakeError:  # an unknown robot: validate_scenarios names it
                self.rate = float("nan")

    # ------------------------------------------------------------------ identity
    def canonical(self) -> dict:
        """The fields that define the run, normalised (floats, sorted keys, lists)."""
        d = asdict(self)
        d.pop("label")
        d["rate"] = float(d["rate"])
        d["duration"] = None if d["duration"] is None else float(d["duration"])
        d["seed"] = int(d["seed"])  # becomes float below; ids only need stability
        d["friction"] = bool(d["friction"])
        d["friction_compensation"] = bool(d["friction_compensation"])
        if d["true_theta"] is not None:
            d["true_theta"] = [float(x) for x in d["true_theta"]]
        return _normalise(d)

    @property
    def id(self) -> str:
        """Stable 16-hex-digit id: equal scenarios get equal ids in every process and run."""
        text = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @property
    def name(self) -> str:
        """A short readable name (``label`` when given)."""
        if self.label:
            return self.label
        parts = [self.robot, self.load, self.controller, self.trajectory, f"{self.rate:g}Hz",
                 self.observer]
        if self.friction_compensation:
            parts.append("fc")
        if self.draw is not None:
            parts.append(f"draw{self.draw}")
        parts.append(f"s{self.seed}")
        return "/".join(str(p) for p in parts)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Scenario":
        """A scenario from plain data; a ClosedLoopConfig field that is no scenario field
        (``torque_limit``, ``model``, ``metrics_skip``, ...) is an override too (into ``extra``)."""
        known = {f.name for f in fields(cls)}
        d = _overrides_into_extra(d, known)
        unknown = set(d) - known
        if unknown:
            raise RobustDrakeError(
                f"unknown scenario field(s) {sorted(unknown)}; known: {sorted(known)}")
        _check_field_types(d)
        return cls(**d)

    # ------------------------------------------------------------------ to the builder
    def to_config(self):
        """The :class:`robust_drake.diagram.ClosedLoopConfig` of this scenario.

        Derived from the two dataclasses' fields: every field both have is copied (through
        :data:`_TO_CONFIG` where a plain-data form needs converting); ``extra`` may set any other
        ClosedLoopConfig field (``effects`` pairs become tuples, ``plant_setup`` entries
        callables); ``friction: false`` means ``plant_friction=None``; the seed is passed on when
        the config has one.  A new ClosedLoopConfig field is thus reachable from scenarios as is."""
        from robust_drake.diagram import ClosedLoopConfig

        config_fields = {f.name for f in fields(ClosedLoopConfig)}
        shared = config_fields & {f.name for f in fields(self)} - _NOT_COPIED
        kwargs = {k: _TO_CONFIG.get(k, _copy)(getattr(self, k)) for k in shared}
        if not self.friction:
            kwargs["plant_friction"] = None
        allowed = config_fields - shared - _NOT_COPIED
        for k, v in self.extra.items():
            if k not in allowed:
                raise RobustDrakeError(
                    f"scenario extra field {k!r} is not a ClosedLoopConfig option; "
                    f"allowed: {sorted(allowed)}")
            kwargs[k] = _EXTRA_TO_CONFIG.get(k, _copy)(v)
        if "seed" in config_fields:  # if the builder grows randomness it gets the seed
            kwargs["seed"] = int(self.seed)
        return ClosedLoopConfig(**kwargs)

    def structure_key(self) -> str:
        """Scenarios with equal keys share one built Diagram (they differ only in what
        :meth:`ClosedLoop.simulate` reads per run: true_theta, duration, initial_q, the
        metrics window, plant_setup). The seed stays in the key: a block seeded at build
        time must not be reused across seeds."""
        d = self.canonical()
        for k in ("true_theta", "duration", "draw", "tags"):
            d.pop(k, None)
        d["extra"] = {k: v for k, v in d["extra"].items()
                      if k not in ("initial_q", "metrics_skip", "metrics_dt", "plant_setup")}
        return json.dumps(d, sort_keys=True, separators=(",", ":"))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_field_types(d: dict) -> None:
    """RobustDrakeError (one line naming the field) for a value of the wrong kind: a text where a
    number belongs (``rates: ['fast']``), a non-positive rate or duration, a non-whole seed."""
    for key in ("robot", "load", "controller", "trajectory", "observer"):
        if key in d and not isinstance(d[key], str):
            raise RobustDrakeError(f"scenario field {key!r} must be a name, got {d[key]!r}")
    if "rate" in d and not (_is_number(d["rate"]) and d["rate"] > 0):
        raise RobustDrakeError(f"scenario field 'rate' must be a number > 0 [Hz], got {d['rate']!r}")
    if d.get("duration") is not None and not (_is_number(d["duration"]) and d["duration"] > 0):
        raise RobustDrakeError(f"scenario field 'duration' must be a number > 0 [s] or null, got {d['duration']!r}")
    for key in ("seed", "draw"):
        v = d.get(key)
        if v is not None and not (_is_number(v) and float(v) == int(v)):
            raise RobustDrakeError(f"scenario field {key!r} must be a whole number, got {v!r}")
    for key in ("friction", "friction_compensation"):
        if key in d and not isinstance(d[key], bool):
            raise RobustDrakeError(f"scenario field {key!r} must be true or false, got {d[key]!r}")
    for key in ("controller_params", "trajectory_params", "observer_params", "tags", "extra"):
        if key in d and not isinstance(d[key], dict):
            raise RobustDrakeError(f"scenario field {key!r} must be a mapping, got {d[key]!r}")
    if d.get("true_theta") is not None and not (isinstance(d["true_theta"], (list, tuple))
                                                and all(_is_number(x) for x in d["true_theta"])):
        raise RobustDrakeError(f"scenario field 'true_theta' must be a list of numbers, got {d['true_theta']!r}")


def config_only_fields() -> set:
    """ClosedLoopConfig fields that are not Scenario fields (given to a scenario via ``extra``)."""
    from robust_drake.diagram import ClosedLoopConfig

    return {f.name for f in fields(ClosedLoopConfig)} - {f.name for f in fields(Scenario)} - _NOT_COPIED


def _overrides_into_extra(d: dict, known: set) -> dict:
    """``d`` with its ClosedLoopConfig-only keys moved into ``extra`` (a key given both ways is refused)."""
    moved = {k: d[k] for k in set(d) - known if k in config_only_fields()}
    if not moved:
        return d
    out = {k: v for k, v in d.items() if k not in moved}
    extra = dict(out.get("extra") or {})
    twice = sorted(set(extra) & set(moved))
    if twice:
        raise RobustDrakeError(f"{twice} given both as a field and in 'extra'")
    out["extra"] = {**extra, **moved}
    return out


def _plant_setup_callable(entry):
    """``["module:function", {params}]`` -> ``f(plant, plant_context)``
    (:func:`robust_drake.diagram.plant_setup_callable`)."""
    from robust_drake.diagram import plant_setup_callable

    return plant_setup_callable(entry)


def _normalise(x):
    """JSON-stable form: tuples -> lists, numpy scalars/arrays -> Python, ints stay ints."""
    if isinstance(x, dict):
        return {str(k): _normalise(v) for k, v in sorted(x.items(), key=lambda kv: str(kv[0]))}
    if isinstance(x, (list, tuple)):
        return [_normalise(v) for v in x]
    if hasattr(x, "tolist"):
        return _normalise(x.tolist())
    if isinstance(x, int) and not isinstance(x, bool):
        return float(x)  # 1 and 1.0 are the same parameter value
    return x


# ---------------------------------------------------------------------------- product specs

#: Product keys: spec key -> Scenario field. Plural keys take lists; the singular field name
#: is accepted too (scalar or list).
PRODUCT_KEYS = {
    "robot": "robot",
    "trajectory": "trajectory",
    "controllers": "controller",
    "loads": "load",
    "rates": "rate",
    "observers": "observer",
    "friction_compensation": "friction_compensation",
    "seeds": "seed",
}
_SINGULAR_OF = {"robots": "robot", "trajectories": "trajectory", "controller": "controller",
                "load": "load", "rate": "rate", "observer": "observer", "seed": "seed"}
_PER_NAME_PARAMS = {"controller": "controller_params", "observer": "observer_params",
                    "trajectory": "trajectory_params"}


def _as_list(v):
    return list(v) if isinstance(v, (list, tuple)) else [v]


def _choice_entries(field_name: str, value) -> list[dict]:
    """Entries for one product axis; named things may carry params and a label."""
    params_field = _PER_NAME_PARAMS.get(field_name)
    if isinstance(value, dict) and params_field:  # {sp1: {...}, sp2: {...}}
        return [{field_name: str(k), params_field: dict(v or {})} for k, v in value.items()]
    out = []
    for v in _as_list(value):
        if isinstance(v, dict):
            if not params_field or "name" not in v:
                raise RobustDrakeError(
                    f"spec: entries of {field_name!r} given as mappings need a 'name' "
                    f"(and optional 'params', 'label'), got {v!r}")
            unknown = set(v) - {"name", "params", "label"}
            if unknown:
                raise RobustDrakeError(f"spec: unknown keys {sorted(unknown)} in {v!r}")
            e = {field_name: str(v["name"]), params_field: dict(v.get("params") or {})}
            if v.get("label"):
                e["_label"] = str(v["label"])
            out.append(e)
        else:
            out.append({field_name: v})
    if not out:
        raise RobustDrakeError(f"spec: {field_name!r} has an empty list")
    return out


#: most scenarios one spec may expand to (each is at least one closed-loop simulation: 1e5 runs
#: of ~1 s are over a day of CPU on one core); :func:`count_product` refuses more before expanding
MAX_SCENARIOS = 100_000


def count_product(spec: dict) -> int:
    """Number of scenarios the product keys of ``spec`` multiply to, counted from the lists'
    lengths without building anything; RobustDrakeError above :data:`MAX_SCENARIOS`."""
    sizes = []
    for key, value in spec.items():
        field_name = PRODUCT_KEYS.get(key) or _SINGULAR_OF.get(key)
        if field_name is not None:
            sizes.append((key, len(value) if isinstance(value, (list, tuple, dict)) else 1))
    total = math.prod(n for _, n in sizes)
    if total > MAX_SCENARIOS:
        raise RobustDrakeError(
            f"spec: the product of its lists is {total:,} scenarios ({' x '.join(f'{n} {k}' for k, n in sizes if n > 1)}): "
            f"more than the limit of {MAX_SCENARIOS:,} (robust_drake.scenario.MAX_SCENARIOS); split the spec "
            "into smaller batches or use the list form")
    return total


def expand_product(spec: dict) -> list[Scenario]:
    """Expand a product spec (see the module docstring) into scenarios, in a stable order.

    Keys that are not product keys are scalar defaults for every scenario (any
    :class:`Scenario` field, e.g. ``duration``, ``friction``, ``controller_params``).
    ``controller_params`` / ``observer_params`` / ``trajectory_params`` may be keyed by the
    controller/observer/trajectory name.
    """
    spec = dict(spec)
    spec.pop("scenarios", None)
    count_product(spec)  # refuse a huge product before building anything
    axes: list[list[dict]] = []
    defaults: dict = {}
    scenario_fields = {f.name for f in fields(Scenario)}
    for key, value in spec.items():
        field_name = PRODUCT_KEYS.get(key) or _SINGULAR_OF.get(key)
        if field_name is not None:
            axes.append(_choice_entries(field_name, value))
        elif key in scenario_fields:
            defaults[key] = value
        elif key in config_only_fields():  # a ClosedLoopConfig override for every scenario
            defaults.setdefault("extra", {})
            defaults["extra"] = {**defaults["extra"], key: value}
        else:
            raise RobustDrakeError(
                f"spec: unknown key {key!r}; product keys: {sorted(PRODUCT_KEYS)}, "
                f"scenario fields: {sorted(scenario_fields)}")
    per_name = {}
    for field_name, params_field in _PER_NAME_PARAMS.items():
        p = defaults.get(params_field)
        # {sp1: {...}, sp2: {...}} keyed by name (values are dicts) vs plain params for all
        if isinstance(p, dict) and p and all(isinstance(v, dict) for v in p.values()):
            per_name[field_name] = defaults.pop(params_field)
    scenarios = []
    for combo in itertools.product(*axes) if axes else [()]:
        d = dict(defaults)
        label_parts = []
        for entry in combo:
            entry = dict(entry)
            if "_label" in entry:
                label_parts.append(entry.pop("_label"))
            d.update(entry)
        for field_name, table in per_name.items():
            name = d.get(field_name, getattr(Scenario, field_name, None))
            params_field = _PER_NAME_PARAMS[field_name]
            if name in table and not d.get(params_field):
                d[params_field] = dict(table[name])
        s = Scenario.from_dict(d)
        if label_parts:
            s.label = "/".join(label_parts + [s.load, f"{s.rate:g}Hz", f"s{s.seed}"])
        scenarios.append(s)
    return scenarios


def scenarios_from_records(records: Iterable[dict], defaults: dict | None = None) -> list[Scenario]:
    """Scenarios from a list of mappings (YAML ``scenarios:`` list or CSV rows)."""
    out = []
    if not isinstance(records, (list, tuple)):
        raise RobustDrakeError(f"'scenarios' must be a list of mappings, got {type(records).__name__}")
    for i, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise RobustDrakeError(
                f"scenario #{i + 1} must be a mapping of scenario fields (e.g. "
                f"{{controller: sp1, load: max}}), got {type(rec).__name__} {rec!r}")
        d = dict(defaults or {})
        rec = dict(rec)
        for key in list(rec):
            if "." in key:  # dotted column: controller_params.epsilon
                head, _, tail = key.partition(".")
                val = rec.pop(key)
                if val is None:
                    continue
                d.setdefault(head, {})
                d[head] = dict(d[head])
                d[head][tail] = val
        d.update({k: v for k, v in rec.items() if v is not None})
        try:
            out.append(Scenario.from_dict(d))
        except (TypeError, RobustDrakeError) as exc:
            raise RobustDrakeError(f"scenario #{i + 1}: {exc}") from None
    return out


_BOOL_TRUE = {"true", "yes", "1", "on"}
_BOOL_FALSE = {"false", "no", "0", "off"}
_DICT_FIELDS = {"controller_params", "trajectory_params", "observer_params", "tags", "extra"}


def _parse_csv_cell(key: str, text: str):
    text = text.strip()
    if text == "":
        return None
    head = key.partition(".")[0]
    if head in ("friction", "friction_compensation"):
        if text.lower() in _BOOL_TRUE:
            return True
        if text.lower() in _BOOL_FALSE:
            return False
        raise RobustDrakeError(f"CSV column {key!r}: expected true/false, got {text!r}")
    if key in _DICT_FIELDS or key == "true_theta" or text[:1] in "[{":
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise RobustDrakeError(f"CSV column {key!r}: invalid JSON {text!r} ({exc})") from None
    if key in ("rate", "duration") or "." in key:
        try:
            return float(text) if key in ("rate", "duration") else _number_or_text(text)
        except ValueError:
            raise RobustDrakeError(f"CSV column {key!r}: expected a number, got {text!r}") from None
    if key in ("seed", "draw"):
        try:
            return int(text)
        except ValueError:
            raise RobustDrakeError(f"CSV column {key!r}: expected an integer, got {text!r}") from None
    return text


def _number_or_text(text):
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def _unique_keys(pairs):
    """json object_pairs_hook: a key given twice is refused (json keeps the last silently)."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise RobustDrakeError(f"key {k!r} appears twice in one mapping; only one would be used")
        out[k] = v
    return out


def yaml_load(text: str):
    """YAML as a batch spec reads it: safe types only; a key repeated in one mapping is refused
    (naming both lines), and numbers in exponent form without a dot or exponent sign (``2.5e3``,
    ``5e-1``, ``1e6``; YAML 1.1 reads them as strings, YAML 1.2 as numbers) are numbers."""
    import re

    import yaml

    class _SpecLoader(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            if key in seen:
                raise RobustDrakeError(f"line {line}: key {key!r} appears twice in one mapping (first at line "
                                       f"{seen[key]}); YAML would keep only the last: remove or merge one")
            seen[key] = line
        return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)

    _SpecLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    _SpecLoader.add_implicit_resolver(
        "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
        list("-+0123456789."))
    return yaml.load(text, Loader=_SpecLoader)  # noqa: S506 - a SafeLoader subclass


def load_spec(path: str | os.PathLike) -> tuple[list[Scenario], dict]:
    """Read a YAML or CSV batch spec. Returns ``(scenarios, spec_document)``.

    The document is what the fingerprint and the results file record (for CSV: the rows).
    Duplicate scenarios (same id) are kept once.
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise RobustDrakeError(f"spec file {path} does not exist")
    if path.is_dir():
        raise RobustDrakeError(f"spec file {path} is a folder")
    try:
        blob = path.read_bytes()  # read once: a FIFO or process substitution works too
    except OSError as exc:
        raise RobustDrakeError(f"cannot read spec file {path}: {exc.strerror or exc}") from None
    try:
        text = blob.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise RobustDrakeError(f"{path}: not a text file (binary content, not UTF-8); a batch spec is "
                               "YAML, JSON or CSV text") from None
    if "\x00" in text:
        raise RobustDrakeError(f"{path}: binary content (NUL bytes); a batch spec is YAML, JSON or CSV text")
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml", ".json"):
        try:
            doc = yaml_load(text) if suffix != ".json" else json.loads(text, object_pairs_hook=_unique_keys)
        except RobustDrakeError as exc:
            raise RobustDrakeError(f"{path}: {exc}") from None
        except Exception as exc:
            raise RobustDrakeError(f"cannot parse {path}: {exc}") from None
        if doc is None:
            raise RobustDrakeError(f"{path} is empty")
        if isinstance(doc, list):
            doc = {"scenarios": doc}
        if not isinstance(doc, dict):
            raise RobustDrakeError(f"{path}: expected a mapping or a list of scenarios")
        if "scenarios" in doc:
            defaults = {k: v for k, v in doc.items() if k != "scenarios"}
            bad = set(defaults) - {f.name for f in fields(Scenario)} - config_only_fields()
            if bad:
                raise RobustDrakeError(
                    f"{path}: with a 'scenarios' list, the other keys must be scenario fields "
                    f"(defaults); unknown: {sorted(bad)}")
            scenarios = scenarios_from_records(doc["scenarios"] or [], defaults)
        else:
            scenarios = expand_product(doc)
    elif suffix == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        if not reader.fieldnames:
            raise RobustDrakeError(f"{path}: no header row")
        rows = [{k.strip(): _parse_csv_cell(k.strip(), v or "") for k, v in row.items() if k}
                for row in reader]
        doc = {"scenarios": rows}
        scenarios = scenarios_from_records(rows)
    else:
        raise RobustDrakeError(f"{path}: spec must be .yaml/.yml/.json or .csv")
    return dedupe(scenarios), doc


def dedupe(scenarios: Iterable[Scenario]) -> list[Scenario]:
    seen, out = set(), []
    for s in scenarios:
        if s.id not in seen:
            seen.add(s.id)
            out.append(s)
    return out


def spec_fingerprint(scenarios: Iterable[Scenario]) -> str:
    """Fingerprint of a batch = hash of its sorted scenario ids (order does not matter)."""
    ids = sorted(s.id for s in scenarios)
    return hashlib.sha256("\n".join(ids).encode()).hexdigest()[:16]


def validate_scenarios(scenarios: Iterable[Scenario]) -> None:
    """Check names against the models and registry tables; raise RobustDrakeError listing
    every problem (not just the first)."""
    from robust_drake import registry
    from robust_drake.models import ROBOTS

    problems = []
    for s in scenarios:
        where = f"scenario {s.name}"
        if s.robot in ROBOTS:
            loads = ROBOTS[s.robot].loads
            if s.load not in loads:
                problems.append(f"{where}: robot {s.robot!r} has no load {s.load!r} "
                                f"(known: {', '.join(loads)})")
        elif not str(s.robot).endswith(".urdf"):
            problems.append(f"{where}: unknown robot {s.robot!r} (known: {', '.join(sorted(ROBOTS))})")
        for kind, name in (("controller", s.controller), ("observer", s.observer),
                           ("trajectory", s.trajectory)):
            if (registry.canonical_or_same(kind, name) not in registry.names(kind)  # any case, paper names
                    and not (kind == "trajectory" and str(name).lower().endswith(".csv"))):
                problems.append(f"{where}: unknown {kind} {name!r}{registry.did_you_mean(str(name), registry.names(kind))} "
                                f"(known: {', '.join(registry.names(kind))})")
        if not (isinstance(s.rate, (int, float)) and math.isfinite(s.rate) and s.rate > 0):
            problems.append(f"{where}: rate must be a positive number of Hz, got {s.rate!r}")
        if s.duration is not None and not (isinstance(s.duration, (int, float)) and s.duration > 0):
            problems.append(f"{where}: duration must be positive, got {s.duration!r}")
        elif s.duration is not None and not problems:
            from robust_drake.diagram import check_run_size

            try:  # refuse a runaway size now, not once per worker
                check_run_size(float(s.duration), float(s.rate))
            except RobustDrakeError as exc:
                problems.append(f"{where}: {exc}")
    if problems:
        uniq = list(dict.fromkeys(problems))
        more = f"\n... and {len(uniq) - 20} more" if len(uniq) > 20 else ""
        raise RobustDrakeError("invalid batch spec:\n  " + "\n  ".join(uniq[:20]) + more)
