#!/usr/bin/env bash
# Build the wheel, install it (exact versions of requirements.lock) into a fresh venv outside
# the checkout and run the package from a folder outside the checkout: the CLI's `simulate` and
# a Python `simulate()` that loads a URDF shipped as package data. Used by `make wheel-check`.
#   usage: .ci/wheel_check.sh BUILD_PYTHON VENV_PYTHON
#   BUILD_PYTHON builds the wheel (a python with pip); VENV_PYTHON (python3.11) makes the venv.
set -euo pipefail
build_python=${1:?build python}
venv_python=${2:?python for the fresh venv}
root=$(cd "$(dirname "$0")/.." && pwd)
tmp=$(mktemp -d "${TMPDIR:-/tmp}/rd-wheel-check.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
cd "$root"

echo "wheel-check: building the wheel"
rm -rf build robust_drake.egg-info          # stale build/lib files would end up in the wheel
"$build_python" -m pip wheel --quiet --no-deps -w "$tmp/dist" .
rm -rf build robust_drake.egg-info
wheel=$(ls "$tmp"/dist/robust_drake-*.whl)

# every URDF of the source tree is in the wheel, as a real file
want=$(cd robust_drake/robots && ls *.urdf | sort)
have=$("$build_python" - "$wheel" <<'PY'
import sys, zipfile
z = zipfile.ZipFile(sys.argv[1])
print("\n".join(sorted(n.rsplit("/", 1)[1] for n in z.namelist()
                        if n.startswith("robust_drake/robots/") and n.endswith(".urdf")
                        and z.getinfo(n).file_size > 0)))
PY
)
if [ "$want" != "$have" ]; then
    echo "error: the wheel's URDFs differ from robust_drake/robots/"; diff <(echo "$want") <(echo "$have") || true
    exit 1
fi
echo "wheel-check: $(echo "$have" | wc -l) URDFs in $(basename "$wheel")"

echo "wheel-check: installing it into a fresh venv with -c requirements.lock"
"$venv_python" -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install --quiet -c requirements.lock --upgrade pip
"$tmp/venv/bin/python" -m pip install --quiet -c requirements.lock "$wheel"

# run from outside the checkout, with nothing of the checkout on the path
mkdir "$tmp/run"
cd "$tmp/run"
unset PYTHONPATH ROBUST_DRAKE_MODELS
echo "wheel-check: robust-drake simulate from $PWD"
"$tmp/venv/bin/robust-drake" simulate --robot d2r2 --controller pd --duration 0.05 --json \
    --plot plots > sim.json
"$tmp/venv/bin/python" - "$root" <<'PY'
import json, math, pathlib, shutil, sys

root = pathlib.Path(sys.argv[1]).resolve()
import robust_drake
from robust_drake.diagram import ClosedLoopConfig, simulate
from robust_drake.models import resolve_urdf

here = pathlib.Path(robust_drake.__file__).resolve()
assert root not in here.parents, f"imported the checkout, not the wheel: {here}"
doc = json.loads(pathlib.Path("sim.json").read_text(),
                 parse_constant=lambda c: sys.exit(f"sim.json holds {c}: not strict JSON"))
assert doc["sim_seconds"] == 0.05 and not doc["diverged"], doc
assert all(math.isfinite(doc[k]) and doc[k] > 0 for k in ("error1", "error2", "error_task")), doc
assert pathlib.Path("plots/tracking.png").stat().st_size > 1000, "no plot written"

urdf = resolve_urdf("d2r2", "max")            # package data of the installed wheel
assert here.parent in urdf.resolve().parents, urdf
res = simulate(ClosedLoopConfig(robot="d2r2", load="max", controller="pd", duration=0.05))
assert res.q.shape[1] == 2 and math.isfinite(res.metrics["error_task"]), res.metrics
mine = shutil.copy(urdf, "my_arm.urdf")        # a user's own URDF path still works
res2 = simulate(ClosedLoopConfig(robot=str(pathlib.Path(mine).resolve()), controller="pd",
                                 duration=0.05, plant_friction=None, encoder_resolution=None))
assert all(math.isfinite(res2.metrics[k]) for k in ("error1", "error2")), res2.metrics
print(f"wheel-check: simulate() from the installed wheel, d2r2 max load: error_task "
      f"{res.metrics['error_task']:.3g} m; own URDF path: error1 {res2.metrics['error1']:.3g} rad")
PY
echo "wheel-check: ok"
