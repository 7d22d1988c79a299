#!/usr/bin/env bash
# Installs the programs nobody here wrote that the interop tests use as witnesses:
# pymodbus (PyPI), mbpoll, curl and mosquitto (Debian) and, for the dashboard's browser test, Debian's
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
python3 -c "import pymodbus; print('pymodbus', pymodbus.__version__)"
mbpoll -V 2>&1 | head -n 1
curl --version | head -n 1
(chromium --version 2>/dev/null || chromium-browser --version) | head -n 1
chromedriver --version | head -n 1
MOSQUITTO="$(command -v mosquitto || echo /usr/sbin/mosquitto)"
"$MOSQUITTO" -h 2>&1 | sed -n 1p || true  # -h exits 3 after printing its version
