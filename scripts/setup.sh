#!/usr/bin/env bash
# Create (or update) the project's virtual environment with ssga-core and every plugin
# installed editable. Idempotent: a second run with nothing changed does nothing.
#
#   VENV=.venv          where the environment lives
#   PYTHON=python3      the interpreter to build it from (3.11 or newer)
#   VENV_FLAGS=         e.g. --system-site-packages to reuse a CUDA torch already installed
#
# torch: if the environment has none, torch==2.13.0 is installed (the CPU build where a
# local wheel is provided). Every later install is constrained to the torch that is
# present, so no dependency can pull another torch (and gigabytes of CUDA packages).
set -euo pipefail
shopt -s nullglob
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}

packages=(ssga_core ssga_bench plugins/*/*/)
# The examples that are packages (examples/hm3d holds configs only).
for example in examples/*/pyproject.toml; do packages+=("${example%pyproject.toml}"); done
stamp="$VENV/.ssga-installed"

# Re-install only when a package's metadata (dependencies, entry points) or this script changed.
if [ -f "$stamp" ] && [ -z "$(find scripts/setup.sh requirements-dev.txt requirements-nodeps.txt "${packages[@]/%//pyproject.toml}" -newer "$stamp" 2>/dev/null)" ]; then
    exit 0
fi

if [ ! -x "$VENV/bin/python" ]; then
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
        || { echo "setup: $PYTHON is $("$PYTHON" -V 2>&1); ssga needs Python 3.11 or newer (set PYTHON=...)" >&2; exit 1; }
    echo "setup: creating $VENV"
    # shellcheck disable=SC2086
    "$PYTHON" -m venv ${VENV_FLAGS:-} "$VENV"
fi
py="$VENV/bin/python"
log="$VENV/setup.log"
: > "$log"
# pip's chatter goes to the log, which is shown only if an install fails.
pip() { "$py" -m pip install --disable-pip-version-check "$@" >> "$log" 2>&1 || { cat "$log" >&2; echo "setup: pip install failed (log: $log)" >&2; exit 1; }; }

torch_version() { "$py" -c 'import importlib.metadata as m; print(m.version("torch"))' 2>/dev/null; }
if ! torch_version >/dev/null; then
    echo "setup: installing $TORCH_SPEC"
    pip "$TORCH_SPEC"
fi
constraints="$VENV/ssga-constraints.txt"
echo "torch==$(torch_version)" > "$constraints"

echo "setup: installing ssga-core and its plugins, ${#packages[@]} packages (editable)"
pip -c "$constraints" hatchling editables
editables=()
# ssga-bench with its `ray` extra: the distributed executor is part of the set-up.
for p in "${packages[@]}"; do
    if [ "$p" = ssga_bench ]; then editables+=(-e "$p[ray]"); else editables+=(-e "$p"); fi
done
pip -c "$constraints" --no-build-isolation "${editables[@]}" -r requirements-dev.txt
# Test-only reference code whose declared dependencies must not come along (see the file).
pip -c "$constraints" --no-deps -r requirements-nodeps.txt
touch "$stamp"
echo "setup: done (torch $(torch_version))"
