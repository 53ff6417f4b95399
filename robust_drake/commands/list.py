"""``robust-drake list``: the robots, controllers, observers, trajectories and plant effects by name,
with their parameters and units (what ``--robot``, ``--controller``, ``--trajectory``,
``--observer`` and the ``*_params`` dictionaries accept)."""

from __future__ import annotations

from robust_drake.cli import add_output_flags, format_table, print_json

WHAT = ("robots", "controllers", "observers", "trajectories", "plant-effects")



def register(sub):
    p = sub.add_parser("list", help="the robots, controllers, observers, trajectories and effects by name",
                       description=__doc__)
    p.add_argument("what", nargs="*", metavar="WHAT",
                   help=f"what to list: {', '.join(WHAT)} (default: all)")
    add_output_flags(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from robust_drake.registry import catalog

    from robust_drake.errors import RobustDrakeError
    from robust_drake.registry import did_you_mean

    for w in args.what:
        if w not in WHAT:
            raise RobustDrakeError(f"list: unknown {w!r}{did_you_mean(w, WHAT)}; give any of {', '.join(WHAT)}")
    cat = catalog()
    keys = [w.replace("-", "_") for w in (args.what or WHAT)]
    doc = {k: cat[k] for k in keys}
    if args.json:
        print_json(doc)
        return 0
    for k in keys:
        print(f"== {k.replace('_', ' ')} ==")
        if k == "robots":
            print(format_table([[r["name"], r["joints"], ",".join(r["loads"]), r["sample_rate"] or "-",
                                 _short(r["summary"], 70)] for r in doc[k]],
                               ["name", "joints", "loads", "rate Hz", "summary"]))
        else:
            for r in doc[k]:
                alias = f" ({r['paper_name']})" if r["paper_name"] != r["name"] else ""
                paper = f" [{r['paper']}]" if r.get("paper") else ""
                print(f"{r['name']}{alias}: {r['summary']}{paper}")
                for par in r["parameters"]:
                    print(f"    {par['name']} [{par['unit']}]" + (f": {par['description']}" if par["description"] else ""))
        print()
    return 0


def _short(text, n):
    text = text or ""
    return text if len(text) <= n else text[: n - 3] + "..."
