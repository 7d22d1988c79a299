#!/usr/bin/env bash
# Installs the programs nobody here wrote that the interop tests use as witnesses:
# pymodbus (PyPI), mbpoll, curl, mosquitto and tshark (Debian) and, for the dashboard's browser test, Debian's
# chromium and chromium-driver (chromedriver). Idempotent.
set -euo pipefail
if ! python3 -c "import pymodbus, serial" 2>/dev/null; then
  # Debian marks its Python "externally managed": fall back to --break-system-packages, and
  # install pip itself first where it is missing.
  python3 -m pip --version >/dev/null 2>&1 || {
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get install -y -q python3-pip >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q python3-pip >/dev/null; }
  }
  python3 -m pip install --quiet "pymodbus==3.16.1" pyserial 2>/dev/null \
    || python3 -m pip install --quiet --break-system-packages "pymodbus==3.16.1" pyserial
fi
if ! command -v mbpoll >/dev/null; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get install -y -q mbpoll >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q mbpoll >/dev/null; }
fi
if ! command -v curl >/dev/null; then
  # curl drives `drivebus serve` in crates/cli/tests/serve.rs (it falls back to plain HTTP/1.1).
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get install -y -q curl >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q curl >/dev/null; }
fi
if ! command -v chromedriver >/dev/null || ! { command -v chromium >/dev/null || command -v chromium-browser >/dev/null; }; then
  # Headless Chromium and its WebDriver run the dashboard's browser test (crates/cli/tests/dashboard.rs).
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get install -y -q chromium chromium-driver >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q chromium chromium-driver >/dev/null; }
fi
# The MQTT broker the gateway's MQTT test starts on a free port (crates/gateway/tests/mqtt_mosquitto.rs).
if ! command -v mosquitto >/dev/null && [ ! -x /usr/sbin/mosquitto ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get install -y -q mosquitto >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q mosquitto >/dev/null; }
fi
# tshark decodes the captures of `drivebus sniff --write` (crates/cli/tests/sniff.rs); its
# question about letting non-root users capture is answered no (nothing here captures packets).
if ! command -v tshark >/dev/null; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "wireshark-common wireshark-common/install-setuid boolean false" | $SUDO debconf-set-selections 2>/dev/null || true
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q tshark >/dev/null 2>&1 || { $SUDO apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q tshark >/dev/null; }
fi
python3 -c "import pymodbus; print('pymodbus', pymodbus.__version__)"
mbpoll -V 2>&1 | head -n 1
curl --version | head -n 1
(chromium --version 2>/dev/null || chromium-browser --version) | head -n 1
chromedriver --version | head -n 1
MOSQUITTO="$(command -v mosquitto || echo /usr/sbin/mosquitto)"
"$MOSQUITTO" -h 2>&1 | sed -n 1p || true  # -h exits 3 after printing its version
tshark --version 2>/dev/null | head -n 1
