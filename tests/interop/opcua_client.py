#!/usr/bin/env python3
"""An OPC UA client nobody here wrote (asyncua, PyPI) against `drivebus serve`.

    opcua_client.py mkcert DIR
        makes a client certificate (DIR/client.der) and key (DIR/client.pem) for signed and
        encrypted sessions; the gateway trusts it through [opcua] trusted_clients.
    opcua_client.py check URL TOKEN DRIVES OFFLINE TRIPPED CONTROL CERTDIR
        URL      opc.tcp://HOST:PORT of the gateway
        TOKEN    the write token of user "demo"
        DRIVES   every drive id, comma-separated
        OFFLINE  a drive on a port that does not exist
        TRIPPED  a drive on a `drivebus simulate` process, tripped here through CONTROL
        CONTROL  http://HOST:PORT of that simulator's control interface

Prints one line per check and exits 0 when every check passed, 1 otherwise.
"""

import asyncio
import json
import sys
import time
import urllib.request
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

PATIENCE = 60.0


def say(what):
    print(what, flush=True)


async def until(what, probe, patience=PATIENCE):
    """Waits (generously) until `probe()` returns a true value, which it returns."""
    deadline = time.monotonic() + patience
    last = None
    while time.monotonic() < deadline:
        try:
            last = await probe()
            if last:
                return last
        except ua.UaError as e:
            last = e
        await asyncio.sleep(0.1)
    raise AssertionError(f"{what}: still {last!r} after {patience} s")


async def mkcert(folder):
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    await setup_self_signed_certificate(
        folder / "client.pem",
        folder / "client.der",
        "urn:drivebus:test:client",
        "localhost",
        [ExtendedKeyUsageOID.CLIENT_AUTH],
        {"countryName": "DE", "organizationName": "drivebus tests"},
    )
    say(f"certificate {folder / 'client.der'}")


def node(client, ns, path):
    return client.get_node(f"ns={ns};s={path}")


async def status_of(call):
    try:
        await call
    except ua.UaStatusCodeError as e:
        return ua.StatusCode(e.code).name
    return "Good"


class Changes:
    """Collects data change and event notifications."""

    def __init__(self):
        self.values = []
        self.events = []

    def datachange_notification(self, node, val, data):
        self.values.append(val)

    def event_notification(self, event):
        self.events.append(event)

    def status_change_notification(self, status):
        pass


async def check(url, token, drives, offline, tripped, control, certdir):
    drives = drives.split(",")
    online = [d for d in drives if d != offline]

    # Anonymous: browse and read.
    async with Client(url) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        folder = await c.nodes.objects.get_child([f"{ns}:Drives"])
        found = sorted([(await k.read_browse_name()).Name for k in await folder.get_children()])
        assert found == sorted(drives), f"Objects/Drives has {found}, expected {sorted(drives)}"
        say(f"browse: Objects/Drives has all {len(found)} drives")

        names = ["OutputFrequency", "Setpoint", "Current", "Running", "Direction", "FaultCode",
                 "FaultText", "Online", "AgeMs", "ErrorRate"]
        for d in online:
            async def good(d=d):
                values = [await node(c, ns, f"Drives/{d}/{n}").read_data_value(raise_on_bad_status=False)
                          for n in names]
                return values if all(v.StatusCode_.is_good() for v in values) else None
            values = await until(f"every variable of {d} Good", good)
            for n, v in zip(names, values):
                assert v.SourceTimestamp is not None, f"{d}/{n} has no source timestamp"
        say(f"read: every variable of {len(online)} drives Good, with source timestamps")

        async def no_comm():
            v = await node(c, ns, f"Drives/{offline}/OutputFrequency").read_data_value(raise_on_bad_status=False)
            return v.StatusCode_.name == "BadNoCommunication" and v
        await until(f"{offline} BadNoCommunication", no_comm)
        online_var = await node(c, ns, f"Drives/{offline}/Online").read_value()
        assert online_var is False, f"{offline}/Online is {online_var}"
        say(f"offline: {offline}'s values are BadNoCommunication, Online false")

        eu = await node(c, ns, f"Drives/{online[0]}/OutputFrequency/EngineeringUnits").read_value()
        assert eu.DisplayName.Text == "Hz", f"EngineeringUnits {eu}"
        say("units: OutputFrequency in Hz (EUInformation)")

        pump = node(c, ns, "Drives/pump-1")
        code = await status_of(pump.call_method(f"{ns}:SetSpeed", ua.Variant(40.0, ua.VariantType.Double)))
        assert code == "BadUserAccessDenied", f"anonymous SetSpeed: {code}"
        say("anonymous SetSpeed refused: BadUserAccessDenied")

    # A wrong password is refused.
    bad = Client(url)
    bad.set_user("demo")
    bad.set_password("not-the-token")
    try:
        await bad.connect()
        await bad.disconnect()
        raise AssertionError("a wrong password was accepted")
    except ua.UaStatusCodeError as e:
        say(f"wrong password refused: {ua.StatusCode(e.code).name}")

    # User demo: subscribe, command, see the drive ramp; events; wrong writes.
    c = Client(url)
    c.set_user("demo")
    c.set_password(token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        changes = Changes()
        sub = await c.create_subscription(100, changes)
        hz = node(c, ns, "Drives/pump-1/OutputFrequency")
        await sub.subscribe_data_change(hz)
        await sub.subscribe_events(c.nodes.server)
        pump = node(c, ns, "Drives/pump-1")
        await pump.call_method(f"{ns}:SetSpeed", ua.Variant(40.0, ua.VariantType.Double))
        await pump.call_method(f"{ns}:Run")

        async def reached():
            return any(isinstance(v, float) and abs(v - 40.0) <= 0.1 for v in changes.values)
        await until("OutputFrequency notifications reach 40 Hz", reached, 120)
        ramp = [v for v in changes.values if isinstance(v, float)]
        assert len(set(ramp)) > 3, f"too few changes seen while ramping: {ramp}"
        assert all(a != b for a, b in zip(ramp, ramp[1:])), f"a value published twice in a row: {ramp}"
        say(f"subscription: {len(ramp)} changes while pump-1 ramped to 40 Hz")

        setpoint = node(c, ns, "Drives/pump-1/Setpoint")
        code = await status_of(setpoint.write_value(ua.DataValue(ua.Variant(35, ua.VariantType.Int32))))
        assert code == "BadTypeMismatch", f"Int32 to Setpoint: {code}"
        code = await status_of(hz.write_value(ua.DataValue(ua.Variant(35.0, ua.VariantType.Double))))
        assert code == "BadNotWritable", f"write to OutputFrequency: {code}"
        code = await status_of(pump.call_method(f"{ns}:SetSpeed", ua.Variant(1000.0, ua.VariantType.Double)))
        assert code == "BadOutOfRange", f"SetSpeed 1000 Hz: {code}"
        code = await status_of(setpoint.write_value(ua.DataValue(ua.Variant(35.0, ua.VariantType.Double))))
        assert code == "Good", f"Setpoint 35.0: {code}"
        say("writes: wrong type BadTypeMismatch, read-only BadNotWritable, 1000 Hz BadOutOfRange, Setpoint Good")

        req = urllib.request.Request(f"{control}/drives/1", data=json.dumps({"trip": "over-current"}).encode(),
                                     headers={"Content-Type": "application/json"}, method="POST")
        urllib.request.urlopen(req, timeout=10).read()

        async def tripped_event():
            return [e for e in changes.events if getattr(e, "SourceName", None) == tripped
                    and "trip" in str(e.Message.Text)]
        events = await until(f"a trip event from {tripped} on the Server object", tripped_event)
        say(f"events: {events[0].Message.Text}")

    # Basic256Sha256 SignAndEncrypt with a trusted client certificate.
    c = Client(url)
    await c.set_security(SecurityPolicyBasic256Sha256, str(Path(certdir) / "client.der"),
                         str(Path(certdir) / "client.pem"), mode=ua.MessageSecurityMode.SignAndEncrypt)
    c.application_uri = "urn:drivebus:test:client"
    c.set_user("demo")
    c.set_password(token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        v = await node(c, ns, "Drives/pump-1/Running").read_value()
        assert v is True, f"pump-1 Running {v}"
        say("security: Basic256Sha256 SignAndEncrypt session reads pump-1 running")
    say("ALL OK")


def main():
    if len(sys.argv) >= 3 and sys.argv[1] == "mkcert":
        asyncio.run(mkcert(sys.argv[2]))
    elif len(sys.argv) == 9 and sys.argv[1] == "check":
        try:
            asyncio.run(check(*sys.argv[2:]))
        except AssertionError as e:
            print(f"FAILED: {e}", flush=True)
            sys.exit(1)
    else:
        print(__doc__)
        sys.exit(3)


if __name__ == "__main__":
    main()
