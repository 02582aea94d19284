#!/usr/bin/env bash
# Debian packages for .ci/run's optional steps (libLLVM 19 for Mitsuba's LLVM variant, SLURM and
# munge for the cluster check).
#   .ci/apt.sh update        apt-get update (once per CI run)
#   .ci/apt.sh install PKG…  installs the packages that are missing (none missing: no apt-get)
# Exit status 0 when every package is installed afterwards, else 1 with one line saying why
# (no apt-get, not root, a package or the network missing): the caller skips its step.
set -uo pipefail
cmd=${1:?usage: .ci/apt.sh update | install PKG...}
shift
installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q 'install ok installed'; }
can_apt() {
    command -v apt-get >/dev/null || { echo "apt: no apt-get on this machine" >&2; return 1; }
    [[ $(id -u) -eq 0 ]] || { echo "apt: not root, cannot install packages" >&2; return 1; }
}
case "$cmd" in
update)
    can_apt || exit 1
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null 2>&1 ||
        { echo "apt: apt-get update failed" >&2; exit 1; }
    ;;
install)
    missing=()
    for p in "$@"; do installed "$p" || missing+=("$p"); done
    [[ ${#missing[@]} -eq 0 ]] && exit 0
    can_apt || exit 1
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        "${missing[@]}" >/dev/null 2>&1; then
        echo "apt: could not install ${missing[*]}" >&2
        exit 1
    fi
    ;;
*)
    echo "usage: .ci/apt.sh update | install PKG..." >&2
    exit 2
    ;;
esac
