#!/usr/bin/env bash
# Installs the programs nobody here wrote that the tests use as witnesses: pymodbus, asyncua and
# the Sparkplug host's pysparkplug + paho-mqtt (PyPI); node-opcua (npm, into tests/interop/node); from Debian mbpoll, curl, mosquitto,
# tshark, chromium + chromium-driver (the dashboard's browser test) and systemd (systemd-analyze,
# for the package check); and cargo-deb (crates.io) to build the Debian package. Idempotent:
# each is installed only when missing.
set -euo pipefail

SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
APT_UPDATED=""

# apt_install COMMAND PACKAGE...: installs PACKAGE... from Debian unless COMMAND is already on
# PATH (or in /usr/sbin); updates the package lists once, on the first install that needs it.
apt_install() {
  local cmd="$1"
  shift
  if command -v "$cmd" >/dev/null || [ -x "/usr/sbin/$cmd" ]; then
    return 0
  fi
  local install=($SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$@")
  if [ -z "$APT_UPDATED" ] && ! "${install[@]}" >/dev/null 2>&1; then
    $SUDO apt-get update -q >/dev/null
    APT_UPDATED=1
    "${install[@]}" >/dev/null
  elif [ -n "$APT_UPDATED" ]; then
    "${install[@]}" >/dev/null
  fi
}

# pip_install MODULE REQUIREMENT...: installs the pinned REQUIREMENT... from PyPI unless Python can
# import MODULE. Debian marks its Python "externally managed": fall back to
# --break-system-packages, and install pip itself first where it is missing.
pip_install() {
  local module="$1"
  shift
  if python3 -c "import $module" 2>/dev/null; then
    return 0
  fi
  python3 -m pip --version >/dev/null 2>&1 || apt_install pip3 python3-pip
  python3 -m pip install --quiet "$@" 2>/dev/null \
    || python3 -m pip install --quiet --break-system-packages "$@"
}

# npm_ci FOLDER: installs the npm packages pinned in FOLDER/package-lock.json into
# FOLDER/node_modules (never globally), with Node.js and npm from Debian where npm is missing;
# nothing when what is installed there already matches the lock.
npm_ci() {
  local dir="$1"
  apt_install npm nodejs npm
  if (cd "$dir" && npm ls --all >/dev/null 2>&1); then
    return 0
  fi
  (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
}

pip_install "pymodbus, serial" "pymodbus==3.16.1" pyserial
# The OPC UA client of crates/cli/tests/opcua.rs (tests/interop/opcua_client.py).
pip_install asyncua "asyncua==1.1.5"
# The second OPC UA client stack, node-opcua, of crates/cli/tests/opcua_node.rs
# (tests/interop/node/opcua_client.js; the version is pinned in its package.json and lock).
NODE_WITNESSES="$(cd "$(dirname "$0")/../tests/interop/node" && pwd)"
npm_ci "$NODE_WITNESSES"
# The Python Sparkplug B host of crates/cli/tests/sparkplug.rs: paho-mqtt and the Sparkplug B schema
# as pysparkplug ships it (tests/interop/sparkplug_host.py).
pip_install "pysparkplug._protobuf.sparkplug_b_pb2, paho.mqtt.client" \
  "pysparkplug==0.6.1" "paho-mqtt==1.6.1" "protobuf==7.36.2"
apt_install mbpoll mbpoll
# curl drives `drivebus serve` in crates/cli/tests/serve.rs (it falls back to plain HTTP/1.1).
apt_install curl curl
# Headless Chromium and its WebDriver run the dashboard's browser test (crates/cli/tests/dashboard.rs).
command -v chromium-browser >/dev/null || apt_install chromium chromium chromium-driver
apt_install chromedriver chromium-driver
# The MQTT broker the gateway's MQTT test starts on a free port (crates/gateway/tests/mqtt_mosquitto.rs).
apt_install mosquitto mosquitto
# tshark decodes the captures of `drivebus sniff --write` (crates/cli/tests/sniff.rs); its
# question about letting non-root users capture is answered no (nothing here captures packets).
echo "wireshark-common wireshark-common/install-setuid boolean false" | $SUDO debconf-set-selections 2>/dev/null || true
apt_install tshark tshark
# systemd-analyze verifies the packaged unit (.ci/package.sh).
apt_install systemd-analyze systemd
# cargo-deb builds the Debian package (.ci/package.sh); cargo-fuzz runs the fuzz targets
# (fuzz/run-all.sh) on the nightly toolchain, installed here where it is missing.
cargo_install() { # cargo_install SUBCOMMAND CRATE VERSION
  if ! cargo "$1" --version >/dev/null 2>&1; then
    cargo install "$2" --locked --version "$3" --quiet
  fi
}
cargo_install deb cargo-deb 3.8.0
cargo_install fuzz cargo-fuzz 0.12.0
rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal

python3 -c "import pymodbus; print('pymodbus', pymodbus.__version__)"
python3 -c "import asyncua; print('asyncua', asyncua.__version__)"
python3 -c "import importlib.metadata as m; print(*(f'{p} {m.version(p)}' for p in ('pysparkplug', 'paho-mqtt', 'protobuf')))"
(cd "$NODE_WITNESSES" && node -p "'node-opcua ' + require('node-opcua/package.json').version + ' on Node.js ' + process.version")
mbpoll -V 2>&1 | head -n 1
curl --version | head -n 1
(chromium --version 2>/dev/null || chromium-browser --version) | head -n 1
chromedriver --version | head -n 1
MOSQUITTO="$(command -v mosquitto || echo /usr/sbin/mosquitto)"
"$MOSQUITTO" -h 2>&1 | sed -n 1p || true  # -h exits 3 after printing its version
tshark --version 2>/dev/null | head -n 1
systemd-analyze --version | head -n 1
cargo deb --version
