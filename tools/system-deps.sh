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
#   liburdfdom-tools `check_urdf`: ROS's own URDF parser (urdfdom, what
#                    robot_state_publisher reads with) checks the bridge's robot_description
#   python3-venv, python3-dev  Debian's Python: `python3 -m venv` (README's commands), and
#                    the headers the compiled fast path builds against
#   debootstrap      makes a Debian 13 root with Fast DDS 3 (libfastdds-dev 3.1,
#                    fastddsgen 4, g++), what ROS 2 Kilted and Lyrical run: the second
#                    DDS peer of the ROS 2 tests is built and run from it. It lives in
#                    $CHASSIS_SDK_DEBIAN13 (default /var/cache/chassis-sdk/debian13),
#                    kept between runs: about 1 GB and two minutes, made once, from the
#                    Debian mirror apt already uses.
# Idempotent: does nothing (and never touches apt) when all are present; uses sudo only
# when not root, and only when something is missing.
set -eu

packages="mosquitto fastddsgen libfastrtps-dev libfastcdr-dev g++ iproute2 util-linux
    chromium fonts-dejavu-core tmux liburdfdom-tools python3-venv python3-dev debootstrap"
debian13=${CHASSIS_SDK_DEBIAN13:-/var/cache/chassis-sdk/debian13}

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
command -v check_urdf >/dev/null 2>&1 || need liburdfdom-tools
[ -f /usr/include/fastdds/dds/domain/DomainParticipantFactory.hpp ] || need libfastrtps-dev

# The Debian 13 root is complete once its last step wrote this file.
done_mark="$debian13/.chassis-sdk-complete"

if [ -z "$missing" ] && [ -f "$done_mark" ]; then
    echo "system-deps: all present ($(echo $packages)); Fast DDS 3 in $debian13"
    exit 0
fi

if [ "$(id -u)" -eq 0 ]; then
    as_root=""
elif command -v sudo >/dev/null 2>&1; then
    as_root="sudo"
else
    echo "system-deps: not root and no sudo: as root, run: sh tools/system-deps.sh (it installs:$missing${missing:+;} the Debian 13 root in $debian13 if missing)" >&2
    exit 1
fi

if [ -n "$missing" ]; then
    echo "system-deps: missing:$missing; installing with apt-get"
    # shellcheck disable=SC2086  # $as_root is empty or one word
    $as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    # shellcheck disable=SC2086  # word splitting of the package list is the point
    $as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        $missing >/dev/null
    echo "system-deps: installed"
fi

if [ ! -f "$done_mark" ]; then
    # The mirror apt uses (deb822 sources first, then the one-line format).
    mirror=$(sed -n 's/^URIs:[[:space:]]*\([^[:space:]]*\).*/\1/p' /etc/apt/sources.list.d/*.sources \
        2>/dev/null | grep -v security | head -n 1)
    if [ -z "$mirror" ]; then
        mirror=$(sed -n 's/^deb[[:space:]]\{1,\}\([^[:space:]]*\).*/\1/p' /etc/apt/sources.list \
            2>/dev/null | grep -v security | head -n 1)
    fi
    if [ -z "$mirror" ]; then
        echo "system-deps: no Debian mirror in apt's sources for the Debian 13 root" >&2
        exit 1
    fi
    echo "system-deps: making the Debian 13 root with Fast DDS 3 in $debian13 (about 1 GB, a few minutes)"
    started=$(date +%s)
    $as_root rm -rf "$debian13.partial"
    $as_root mkdir -p "$(dirname "$debian13")"
    log=$(mktemp "${TMPDIR:-/tmp}/debootstrap.XXXXXX")
    $as_root debootstrap --variant=minbase --include=g++,libfastdds-dev,fastddsgen \
        trixie "$debian13.partial" "$mirror" >"$log" 2>&1 || {
        tail -n 20 "$log" >&2
        echo "system-deps: debootstrap failed (log above; all of it in $log)" >&2
        exit 1
    }
    rm -f "$log"
    # The mount point the peer's build binds its directory onto; then the mark, last.
    $as_root mkdir -p "$debian13.partial/build"
    $as_root rm -rf "$debian13"
    $as_root mv "$debian13.partial" "$debian13"
    $as_root touch "$done_mark"
    echo "system-deps: Debian 13 root made in $(( $(date +%s) - started )) s ($(du -sh "$debian13" | cut -f1))"
fi
