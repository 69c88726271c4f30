# Source this (". tools/env.sh") after tools/setup.sh: it activates the virtual
# environment setup.sh made (.venv) when it made one, and gives the shell a
# `python` where only `python3` exists, so that the README's commands run as written.
_taichi_hsdem_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")/.." && pwd)"
if [ -z "${VIRTUAL_ENV:-}" ] && [ -f "$_taichi_hsdem_root/.venv/bin/activate" ]; then
    . "$_taichi_hsdem_root/.venv/bin/activate"
fi
if ! command -v python >/dev/null 2>&1 && command -v python3 >/dev/null 2>&1; then
    python() { python3 "$@"; }
fi
unset _taichi_hsdem_root
