#!/usr/bin/env bash
# Install what sltwin needs on a Debian 12 machine (as root), idempotently.
#   - Debian's python3-mrcal (mrcal 2.2 C core + Python layer),
#   - a virtual environment .venv from the machine's python3 (3.11),
#   - pinned wheels (constraints.txt keeps numpy at 1.26.4 for mrcal's extension),
#   - the mrcal package of /usr/lib/python3/dist-packages made visible in the venv,
#   - sltwin itself, editable.
# WITH_BPY=1 also installs bpy (Blender as a module), used only by tests and --blender.
# A stamp file records what was installed; a second run with unchanged inputs returns at once.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
stamp_inputs="$(cat constraints.txt requirements.txt setup.cfg scripts/bootstrap.sh | sha256sum | cut -c1-16)"
want="$stamp_inputs-bpy${WITH_BPY:-0}"
if [ -f "$VENV/.sltwin-stamp" ]; then
  have=$(cat "$VENV/.sltwin-stamp")
  # an install with bpy also satisfies a request without it
  if [ "$have" = "$want" ] || { [ "${WITH_BPY:-0}" = 0 ] && [ "$have" = "$stamp_inputs-bpy1" ]; }; then
    exit 0
  fi
fi

if [ ! -d /usr/lib/python3/dist-packages/mrcal ]; then
  echo "[bootstrap] installing Debian's python3-mrcal"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends python3-mrcal >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "[bootstrap] creating $VENV with $($PY --version)"
  $PY -m venv "$VENV"
fi
pip_install() { "$VENV/bin/python" -m pip install -q --disable-pip-version-check -c constraints.txt "$@"; }
echo "[bootstrap] installing pinned wheels (first time: a few minutes)"
pip_install -r requirements.txt
if [ "${WITH_BPY:-0}" = 1 ]; then
  echo "[bootstrap] installing bpy (Blender as a module, ~370 MB)"
  pip_install bpy
fi
site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
ln -sfn /usr/lib/python3/dist-packages/mrcal "$site/mrcal"
pip_install --no-deps --no-build-isolation --config-settings editable_mode=compat -e .
"$VENV/bin/python" -c 'import mrcal, numpy, cv2, casadi, torch, kornia, h5py; print("[bootstrap] ok: mrcal", mrcal.__version__ if hasattr(mrcal, "__version__") else "", "numpy", numpy.__version__, "torch", torch.__version__)'
echo "$want" > "$VENV/.sltwin-stamp"
