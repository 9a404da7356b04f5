#!/usr/bin/env bash
# Install what sltwin needs on a Debian 12 machine (as root), idempotently.
#   - Debian's python3-mrcal (mrcal 2.2 C core + Python layer),
#   - a virtual environment .venv from the machine's python3 (3.11),
#   - pinned wheels (constraints.txt keeps numpy at 1.26.4 for mrcal's extension),
#   - the mrcal package of /usr/lib/python3/dist-packages made visible in the venv,
#   - sltwin itself, editable.
# WITH_TEST_TOOLS=1 also installs the test-only tools: bpy (Blender as a module, used only by
# tests and --blender) and Debian's chromium (headless browser test of the HTML reports).
# A stamp file records what was installed; a second run with unchanged inputs returns at once.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
stamp_inputs="$(cat constraints.txt requirements.txt setup.cfg scripts/bootstrap.sh | sha256sum | cut -c1-16)"
want="$stamp_inputs-tools${WITH_TEST_TOOLS:-0}"
if [ -f "$VENV/.sltwin-stamp" ]; then
  have=$(cat "$VENV/.sltwin-stamp")
  # an install with bpy also satisfies a request without it
  if [ "$have" = "$want" ] || { [ "${WITH_TEST_TOOLS:-0}" = 0 ] && [ "$have" = "$stamp_inputs-tools1" ]; }; then
    exit 0
  fi
fi

apt_pkgs=()
[ -d /usr/lib/python3/dist-packages/mrcal ] || apt_pkgs+=(python3-mrcal)
[ "${WITH_TEST_TOOLS:-0}" = 1 ] && ! command -v chromium >/dev/null && apt_pkgs+=(chromium)
if [ ${#apt_pkgs[@]} -gt 0 ]; then
  echo "[bootstrap] installing Debian packages: ${apt_pkgs[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${apt_pkgs[@]}" >/tmp/sltwin-apt.log 2>&1 || {
    tail -20 /tmp/sltwin-apt.log; echo "[bootstrap] apt-get install ${apt_pkgs[*]} failed" >&2; exit 1; }
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "[bootstrap] creating $VENV with $($PY --version)"
  $PY -m venv "$VENV"
fi
# pip, quiet; its noise about this machine's unused local index locations is filtered, its errors are not
pip_install() {
  local log rc=0
  log=$(mktemp)
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -c constraints.txt "$@" >"$log" 2>&1 || rc=$?
  grep -v "^WARNING: Location" "$log" || true
  rm -f "$log"
  [ "$rc" = 0 ] || { echo "[bootstrap] pip install $* failed (exit $rc)" >&2; exit "$rc"; }
}
echo "[bootstrap] installing pinned wheels (first time: a few minutes)"
pip_install -r requirements.txt
if [ "${WITH_TEST_TOOLS:-0}" = 1 ]; then
  echo "[bootstrap] installing bpy (Blender as a module, ~370 MB)"
  pip_install bpy
fi
site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
ln -sfn /usr/lib/python3/dist-packages/mrcal "$site/mrcal"
pip_install --no-deps --no-build-isolation --config-settings editable_mode=compat -e .
"$VENV/bin/python" -c 'import mrcal, numpy, cv2, casadi, torch, kornia, h5py; print("[bootstrap] ok: mrcal", mrcal.__version__ if hasattr(mrcal, "__version__") else "", "numpy", numpy.__version__, "torch", torch.__version__)'
echo "$want" > "$VENV/.sltwin-stamp"
