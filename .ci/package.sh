#!/usr/bin/env bash
# The Debian package, as a user gets it: build it with cargo-deb, list it, extract it into a
# temporary root, run the packaged binary (--version, config check on the packaged example
# configuration) and verify the packaged systemd unit with systemd-analyze.
set -euo pipefail
cd "$(dirname "$0")/.."

cargo deb -p drivebus --strip --quiet
deb="$(ls -t target/debian/drivebus_*.deb | head -n 1)"
echo "-- $deb"
dpkg-deb --info "$deb" | sed -n '/Package:/,/Description:/p'
dpkg-deb --contents "$deb"

root="$(mktemp -d)"
trap 'rm -rf "$root"' EXIT
dpkg-deb --extract "$deb" "$root"
for f in usr/bin/drivebus etc/drivebus/drivebus.toml usr/lib/systemd/system/drivebus.service \
         usr/share/doc/drivebus/operations.md; do
  [ -e "$root/$f" ] || { echo "the package has no /$f" >&2; exit 1; }
done
dpkg-deb --ctrl-tarfile "$deb" | tar -xO ./conffiles | grep -qx /etc/drivebus/drivebus.toml \
  || { echo "/etc/drivebus/drivebus.toml is not a conffile" >&2; exit 1; }

"$root/usr/bin/drivebus" --version | grep -E '^drivebus [0-9.]+ \(commit [0-9a-f]{12}\)$'
"$root/usr/bin/drivebus" config check "$root/etc/drivebus/drivebus.toml"

# The unit as installed, its binary at the extracted path (verify checks that it exists).
unit_dir="$(mktemp -d)"
sed "s#/usr/bin/drivebus#$root/usr/bin/drivebus#g" "$root/usr/lib/systemd/system/drivebus.service" \
  > "$unit_dir/drivebus.service"
out="$(systemd-analyze verify "$unit_dir/drivebus.service" 2>&1)" || { echo "$out" >&2; exit 1; }
if [ -n "$out" ]; then
  echo "systemd-analyze verify: $out" >&2
  exit 1
fi
rm -rf "$unit_dir"
echo "package ok: $deb"
