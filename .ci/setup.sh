# Sourced by .ci/demo and .ci/test: what a fresh machine lacks, installed the Debian way.
#
# Debian 12 and 13 ship python3 without pip or a working venv module (python3-venv) and forbid
# pip outside a virtual environment (PEP 668). So: Debian packages from apt (as root, or through
# sudo), Python packages into the project's own .venv, never into the system's Python.

# The Python that makes .venv: $PYTHON when set, else the first python3 of 3.11 or later among
# the PATH's and Debian's own (a pyenv or an older python3 first on the PATH isn't a dead end).
pick_python() {
  local candidate path
  if [ -n "${PYTHON:-}" ]; then
    candidate=$(command -v "$PYTHON") || { echo "invt-gateway: PYTHON=$PYTHON not found" >&2; return 1; }
    "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 11))' || {
      echo "invt-gateway: PYTHON=$PYTHON is older than Python 3.11" >&2; return 1; }
    echo "$candidate"
    return
  fi
  for candidate in python3 /usr/bin/python3; do
    path=$(command -v "$candidate" 2>/dev/null) || continue
    if "$path" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
      echo "$path"
      return
    fi
  done
  echo "invt-gateway: needs Python 3.11 or later (Debian 12 and later have it as python3)" >&2
  return 1
}

# Run a command as root: directly when root, else through sudo.
as_root() {
  if [ "$(id -u)" = 0 ]; then
    "$@"
  elif command -v sudo >/dev/null 2>&1; then
    sudo "$@"
  else
    echo "invt-gateway: '$*' needs root: run this as root, or install sudo" >&2
    return 1
  fi
}

# True when the Python that makes (or made) .venv has no C headers, which compiling the engine
# room needs: Debian's python3 without python3-dev. The build is Python then, and slower.
python_headers_missing() {
  local python
  if [ -x .venv/bin/python ]; then python=.venv/bin/python; else python=$(pick_python) || return 1; fi
  ! "$python" -c 'import os, sys, sysconfig
sys.exit(not os.path.isfile(os.path.join(sysconfig.get_path("include"), "Python.h")))'
}

# Install Debian packages (names as arguments); nothing when none are given.
install_debian_packages() {
  [ $# -gt 0 ] || return 0
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "invt-gateway: please install $* (no apt-get here: not Debian or Ubuntu)" >&2
    return 1
  fi
  echo "invt-gateway: installing Debian packages: $*" >&2
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}

# .venv with the package installed (editable: the clone is the code), extras as $1 (e.g. test,
# or test,docs: several comma-separated).
# pip runs again only when pyproject.toml changed or other extras are asked for.
setup_venv() {
  local extras=${1:-} python hash stamp have_hash have_extras
  # A .venv without pip is what a `python3 -m venv` without python3-venv leaves: made again.
  if ! .venv/bin/python -m pip --version >/dev/null 2>&1; then
    python=$(pick_python) || return 1
    # Debian ships ensurepip, which `python3 -m venv` needs for pip, in python3-venv.
    if ! "$python" -c 'import ensurepip' 2>/dev/null; then
      case "$python" in
        /usr/bin/*) install_debian_packages python3-venv || return 1 ;;
        *) echo "invt-gateway: $python has no ensurepip: it can't make a virtual environment" >&2
           return 1 ;;
      esac
    fi
    echo "invt-gateway: creating .venv with $python ($("$python" --version 2>&1))" >&2
    rm -rf .venv
    "$python" -m venv .venv
  fi
  # pyproject.toml, and the sources of the modules mypyc compiles: an edit to them builds the
  # engine room again, so that the tests run it compiled as CI does (gateway/compiled.py runs
  # an edited source, never the stale compiled module, meanwhile).
  hash=$(sha256sum pyproject.toml | cut -d' ' -f1)-$(.venv/bin/python -c \
    'from gateway.compiled import source_digest; print(source_digest())')
  stamp=.venv/.invt-gateway-installed
  if [ -f "$stamp" ]; then
    read -r have_hash have_extras < "$stamp" || true
    if [ "$have_hash" = "$hash" ] && { [ -z "$extras" ] || [ "${have_extras:-}" = "$extras" ]; }; then
      return 0
    fi
  fi
  echo "invt-gateway: installing the package${extras:+ with its $extras extras} into .venv (pip)" >&2
  # The build's own decision (gateway/build_backend.py), said before pip's quiet minutes.
  if .venv/bin/python -c 'import sys; from gateway.build_backend import why_not_compiled as w
sys.exit(w() is not None)' 2>/dev/null; then
    echo "invt-gateway: compiling its engine room too (mypyc, with gcc: a minute or two)" >&2
  fi
  # uvloop (the event loop in C) where it comes as a wheel; elsewhere (32-bit ARM) pip would
  # need a compiler for it: the gateway runs on asyncio's own loop there, just as well.
  if ! .venv/bin/python -m pip install -q --disable-pip-version-check --only-binary uvloop \
      -e ".[${extras:+$extras,}uvloop]" 2>/dev/null; then
    echo "invt-gateway: no uvloop wheel for this machine: the gateway will run on asyncio's own loop" >&2
    .venv/bin/python -m pip install -q --disable-pip-version-check -e ".${extras:+[$extras]}"
  fi
  echo "$hash $extras" > "$stamp"
}

# The tests' npm peers (tests/peers/*/package.json with its package-lock.json): Eclipse Tahu's
# JavaScript Sparkplug codec, the Sparkplug tests' independent decoder. `npm ci` again only when
# the lock file changed; no install scripts (none is needed).
setup_node_peers() {
  local peer stamp hash
  for peer in tests/peers/*/package-lock.json; do
    peer=$(dirname "$peer")
    stamp="$peer/node_modules/.invt-gateway-installed"
    hash=$(sha256sum "$peer/package-lock.json" | cut -d' ' -f1)
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$hash" ]; then
      continue
    fi
    echo "invt-gateway: installing the npm packages of $peer (npm ci)" >&2
    (cd "$peer" && npm ci --no-audit --no-fund --ignore-scripts --loglevel=error) || return 1
    echo "$hash" > "$stamp"
  done
}
