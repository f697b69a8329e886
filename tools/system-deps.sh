#!/bin/sh
# The system packages the tests need, from Debian (bookworm or later):
#   mosquitto        the MQTT bridge's tests run a real broker on loopback
#   fastddsgen       eProsima Fast DDS's IDL compiler, and
#   libfastrtps-dev  Fast DDS itself (pulls libfastcdr-dev): the independent DDS peer
#                    (tests/ros2_peer) the ROS 2 bridge's tests talk to on the wire
#   g++              builds that peer
#   iproute2         `ip`, to set up the tests' loopback-only network namespaces
#   util-linux       `unshare`, which makes them
#   chromium         the web dashboard's tests drive Debian's Chromium (headless) through
#                    Playwright, which downloads no browser of its own
#   fonts-dejavu-core  text for Chromium to render (the docs' screenshot, the pages)
#   tmux             the terminal teleop's tests type into a real terminal
#   python3-venv, python3-dev  Debian's Python: `python3 -m venv` (README's commands), and
#                    the headers the compiled fast path builds against
# Idempotent: does nothing (and never touches apt) when all are present; uses sudo only
# when not root, and only when something is missing.
set -eu

packages="mosquitto fastddsgen libfastrtps-dev libfastcdr-dev g++ iproute2 util-linux
    chromium fonts-dejavu-core tmux python3-venv python3-dev"

installed() {
    dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"
}

missing=""
need() {  # need PACKAGE: add it to the missing ones, once
    case " $missing " in
        *" $1 "*) ;;
        *) missing="$missing $1" ;;
    esac
}
for pkg in $packages; do
    installed "$pkg" || need "$pkg"
done
# The commands themselves must be there too (a package can be half removed).
command -v fastddsgen >/dev/null 2>&1 || need fastddsgen
command -v g++ >/dev/null 2>&1 || need g++
command -v ip >/dev/null 2>&1 || [ -x /usr/sbin/ip ] || [ -x /sbin/ip ] || need iproute2
command -v unshare >/dev/null 2>&1 || need util-linux
command -v mosquitto >/dev/null 2>&1 || [ -x /usr/sbin/mosquitto ] || need mosquitto
command -v chromium >/dev/null 2>&1 || need chromium
command -v tmux >/dev/null 2>&1 || need tmux
[ -f /usr/include/fastdds/dds/domain/DomainParticipantFactory.hpp ] || need libfastrtps-dev

if [ -z "$missing" ]; then
    echo "system-deps: all present ($(echo $packages))"
    exit 0
fi
echo "system-deps: missing:$missing; installing with apt-get"

if [ "$(id -u)" -eq 0 ]; then
    as_root=""
elif command -v sudo >/dev/null 2>&1; then
    as_root="sudo"
else
    echo "system-deps: not root and no sudo: as root, run: apt-get install$missing" >&2
    exit 1
fi

# shellcheck disable=SC2086  # $as_root is empty or one word
$as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq
# shellcheck disable=SC2086  # word splitting of the package list is the point
$as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    $missing >/dev/null
echo "system-deps: installed"
