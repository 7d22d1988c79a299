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

    opcua_client.py trust URL WRITE_TOKEN READ_TOKEN CERTDIR MAX_SESSIONS HOST
        URL          opc.tcp://127.0.0.1:PORT of a gateway with drive pump-1, users ops-w (write,
                     WRITE_TOKEN) and ops-r (read, READ_TOKEN), anonymous reads on, the client
                     certificate of CERTDIR trusted, [opcua] max_sessions_per_user = MAX_SESSIONS
        HOST         the host its endpoint URLs must name
        Checks: passwords never sent in clear (every endpoint's user name policy names
        Basic256Sha256), writes and calls refused over None, authorization before the type
        check, writes over Sign and SignAndEncrypt, sessions per user capped.

    opcua_client.py history URL HTTP DRIVE
        URL      opc.tcp://HOST:PORT of a gateway with a store, DRIVE running
        HTTP     http://HOST:PORT of its HTTP API (anonymous reads on)
        Checks: DRIVE's OutputFrequency is Historizing with AccessLevel HistoryRead (Running is
        not), and read_raw_history over the last minute gives the points of
        GET /api/drives/DRIVE/trend for the same span; in pages of 2 values through continuation
        points the same; with the end before the start, newest first.

    opcua_client.py big URL COUNT
        URL      opc.tcp://HOST:PORT of a gateway with COUNT drives vfd-1..vfd-COUNT
        Checks: Objects/Drives lists all COUNT drives; a drive's Parameters browse and one of them
        reads Good from the drive; a drive variable of the last drive reads.

    opcua_client.py template URL TOKEN DRIVE
        URL      opc.tcp://HOST:PORT of a gateway with DRIVE of a kind made from the generic-2000h
                 template with [values] dc_bus_v (V) and power_kw (kW); insecure_writes on
        TOKEN    the write token of user "demo"
        Checks: Objects/Drives lists DRIVE, its OutputFrequency reads Good, its Values folder
        holds dc_bus_v and power_kw, dc_bus_v reads Good (the simulated DC bus) with
        EngineeringUnits V (UnitId VLT), a subscription to power_kw is notified of the power
        once SetSpeed(20.0) and Run bring the drive to 20 Hz, and Parameters/P0.04 (the
        template's name) reads 50.0 from the drive.

    opcua_client.py standby URL TOKEN DRIVE BUS
        URL      opc.tcp://HOST:PORT of a gateway that is a standby on BUS (another gateway
                 masters the line, [standby]); insecure_writes on
        TOKEN    the write token of user "demo"
        Checks: DRIVE's Source and BUS's Role read "standby" (Good); a write to DRIVE's
        Setpoint and a call of its Run are refused with Bad_InvalidState.

    opcua_client.py order URL HTTP TOKEN DRIVE COUNT
        URL      opc.tcp://HOST:PORT of a gateway with a store and DRIVE; insecure_writes on
        HTTP     http://HOST:PORT of its HTTP API (anonymous reads on)
        TOKEN    the write token of user "demo"
        Checks: COUNT method calls to DRIVE (SetSpeed 10 + i % 40 Hz, Run, Stop, over
        and over) sent on one
        session without waiting for each answer are all Good, the audit trail lists them in the
        order they were sent, and the drive ends in the last commanded state.

    opcua_client.py items URL HTTP DRIVES
        URL      opc.tcp://HOST:PORT of a gateway with (at least) the two drives of DRIVES,
                 comma-separated, anonymous reads on
        HTTP     http://HOST:PORT of its HTTP API (anonymous reads on)
        Checks: drivebus_opcua_monitored_items in GET /metrics counts the items subscribed to
        (OutputFrequency, Current and Running of each drive, and events of the Server object)
        and falls back to 0 when the client deletes its subscription, when another closes its
        session (CloseSession, deleting its subscriptions), and when a third, with a short
        subscription lifetime, drops its connection without closing anything (the subscription
        expires).

Prints one line per check and exits 0 when every check passed, 1 otherwise.
"""

import asyncio
import json
import logging
import sys
import time
import urllib.request
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import urlparse

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


def unix_ms(t):
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return round(t.timestamp() * 1000)


def at_ms(ms):
    return datetime.fromtimestamp(ms / 1000, tz=timezone.utc)


async def paged(n, since, until, per_page):
    """A raw history read through continuation points, `per_page` values at a time."""
    details = ua.ReadRawModifiedDetails()
    details.IsReadModified = False
    details.StartTime = at_ms(since)
    details.EndTime = at_ms(until)
    details.NumValuesPerNode = per_page
    details.ReturnBounds = False
    values, cp, pages = [], None, 0
    while True:
        r = await n.history_read(details, cp)
        r.StatusCode.check()
        page = r.HistoryData.DataValues or []
        assert len(page) <= per_page, f"a page of {len(page)} values, asked for {per_page}"
        values += page
        pages += 1
        cp = r.ContinuationPoint
        if not cp:
            return values, pages


async def history(url, http, drive):
    def trend(since, until):
        with urllib.request.urlopen(f"{http}/api/drives/{drive}/trend?since={since}&until={until}", timeout=10) as r:
            return [(p["time_ms"], p["output_hz"]) for p in json.load(r) if p["output_hz"] is not None]

    async with Client(url) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        hz = node(c, ns, f"Drives/{drive}/OutputFrequency")
        hist = (await hz.read_attribute(ua.AttributeIds.Historizing)).Value.Value
        assert hist is True, f"OutputFrequency Historizing {hist}"
        level = (await hz.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value
        assert level & ua.AccessLevel.HistoryRead.mask, f"OutputFrequency AccessLevel {level}"
        running = node(c, ns, f"Drives/{drive}/Running")
        assert (await running.read_attribute(ua.AttributeIds.Historizing)).Value.Value is False, "Running Historizing"
        say("history: OutputFrequency Historizing with HistoryRead access, Running not")

        async def enough():
            now = round(time.time() * 1000)
            return len(trend(now - 60_000, now)) >= 5
        await until(f"5 trend points of {drive}", enough)

        async def same():
            until_ms = round(time.time() * 1000)
            since = until_ms - 60_000
            before = trend(since, until_ms)
            got = [(unix_ms(v.SourceTimestamp), v.Value.Value) for v in
                   await hz.read_raw_history(at_ms(since), at_ms(until_ms))]
            pages, n = await paged(hz, since, until_ms, 2)
            pages = [(unix_ms(v.SourceTimestamp), v.Value.Value) for v in pages]
            back, _ = await paged(hz, until_ms, since, 1000)
            back = [(unix_ms(v.SourceTimestamp), v.Value.Value) for v in back]
            after = trend(since, until_ms)
            # The store was still writing the span's last second: ask again.
            if before != after:
                return None
            assert got == before, f"read_raw_history {got}\n  HTTP trend {before}"
            assert pages == before, f"in pages of 2: {pages}\n  HTTP trend {before}"
            assert n >= len(before) // 2, f"{len(before)} values in {n} pages of 2"
            assert back == before[::-1], f"end before start: {back}"
            return (len(got), n)
        count, n = await until("a span the store had finished writing", same)
        say(f"history: read_raw_history of {drive}/OutputFrequency over the last minute = the HTTP trend "
            f"({count} values; in {n} pages of 2 through continuation points; newest first when asked)")
    say("ALL OK")


async def big(url, count):
    count = int(count)
    async with Client(url, timeout=60) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        folder = await c.nodes.objects.get_child([f"{ns}:Drives"])
        found = {(await k.read_browse_name()).Name for k in await folder.get_children()}
        expected = {f"vfd-{i}" for i in range(1, count + 1)}
        assert found == expected, f"Objects/Drives: {len(found)} drives, {len(expected - found)} missing"
        say(f"browse: Objects/Drives lists all {count} drives")

        d = f"vfd-{count // 2}"
        params = await node(c, ns, f"Drives/{d}/Parameters").get_children()
        assert params, f"{d}/Parameters is empty"
        p = params[0]
        name = (await p.read_browse_name()).Name

        async def good():
            v = await p.read_data_value(raise_on_bad_status=False)
            return v.StatusCode_.is_good() and v
        v = await until(f"{d}/Parameters/{name} read Good", good)
        assert isinstance(v.Value.Value, float), f"{d}/Parameters/{name} = {v.Value!r}"
        say(f"parameters: {d} has {len(params)}; {name} reads {v.Value.Value} from the drive")

        last = await c.nodes.objects.get_child([f"{ns}:Drives", f"{ns}:vfd-{count}", f"{ns}:Online"])
        async def online():
            return await last.read_value() is True
        await until(f"vfd-{count} online", online)
        say(f"read: vfd-{count}/Online true, found by its browse path")
    say("ALL OK")


class PlainText(logging.Handler):
    """Catches asyncua's warning that it sends a password in clear."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.seen = []

    def emit(self, record):
        if "plain-text" in record.getMessage():
            self.seen.append(record.getMessage())


async def trust(url, write_token, read_token, certdir, max_sessions, host):
    max_sessions = int(max_sessions)
    plain = PlainText()
    logging.getLogger("asyncua.client.client").addHandler(plain)
    b256 = SecurityPolicyBasic256Sha256.URI

    c = Client(url)
    endpoints = await c.connect_and_get_server_endpoints()
    assert len(endpoints) == 3, f"{len(endpoints)} endpoints"
    for ep in endpoints:
        assert urlparse(ep.EndpointUrl).hostname == host, f"endpoint URL {ep.EndpointUrl}, expected host {host}"
        users = [p for p in ep.UserIdentityTokens if p.TokenType == ua.UserTokenType.UserName]
        assert users and all(p.SecurityPolicyUri == b256 for p in users), \
            f"{ep.SecurityPolicyUri} {ep.SecurityMode}: user name policies {users}"
    say(f"endpoints: all 3 at host {host}, passwords encrypted with Basic256Sha256 on each, None included")

    async def secure(mode, user, token):
        c = Client(url)
        await c.set_security(SecurityPolicyBasic256Sha256, str(Path(certdir) / "client.der"),
                             str(Path(certdir) / "client.pem"), mode=mode)
        c.application_uri = "urn:drivebus:test:client"
        c.set_user(user)
        c.set_password(token)
        return c

    double = ua.DataValue(ua.Variant(30.0, ua.VariantType.Double))
    int32 = ua.DataValue(ua.Variant(30, ua.VariantType.Int32))

    # The writer over None: logs in (its password encrypted), but may not write nor call.
    c = Client(url)
    c.set_user("ops-w")
    c.set_password(write_token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        pump = node(c, ns, "Drives/pump-1")
        setpoint = node(c, ns, "Drives/pump-1/Setpoint")
        for what, call in [("Setpoint 30.0", setpoint.write_value(double)),
                           ("SetSpeed 30.0", pump.call_method(f"{ns}:SetSpeed", ua.Variant(30.0, ua.VariantType.Double))),
                           ("Run", pump.call_method(f"{ns}:Run"))]:
            code = await status_of(call)
            assert code == "BadSecurityModeInsufficient", f"{what} over None: {code}"
    assert not plain.seen, f"asyncua sent a password in clear: {plain.seen}"
    say("None: login as ops-w without a plain-text password; Setpoint, SetSpeed, Run refused BadSecurityModeInsufficient")

    # Anonymous and read role: refused before the value's type is looked at.
    async with Client(url) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        code = await status_of(node(c, ns, "Drives/pump-1/Setpoint").write_value(int32))
        assert code == "BadUserAccessDenied", f"anonymous Int32 to Setpoint: {code}"
        code = await status_of(node(c, ns, "Drives/pump-1").call_method(
            f"{ns}:SetSpeed", ua.Variant("fast", ua.VariantType.String)))
        assert code == "BadUserAccessDenied", f"anonymous SetSpeed(String): {code}"
    async with await secure(ua.MessageSecurityMode.SignAndEncrypt, "ops-r", read_token) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        code = await status_of(node(c, ns, "Drives/pump-1/Setpoint").write_value(int32))
        assert code == "BadUserAccessDenied", f"ops-r Int32 to Setpoint: {code}"
    say("authorization first: anonymous and ops-r writes of the wrong type BadUserAccessDenied")

    # The writer over Sign and over SignAndEncrypt.
    for mode in (ua.MessageSecurityMode.Sign, ua.MessageSecurityMode.SignAndEncrypt):
        async with await secure(mode, "ops-w", write_token) as c:
            ns = await c.get_namespace_index("urn:drivebus")
            setpoint = node(c, ns, "Drives/pump-1/Setpoint")
            code = await status_of(setpoint.write_value(int32))
            assert code == "BadTypeMismatch", f"ops-w Int32 to Setpoint over {mode.name}: {code}"
            code = await status_of(setpoint.write_value(double))
            assert code == "Good", f"ops-w Setpoint 30.0 over {mode.name}: {code}"
    say("Sign and SignAndEncrypt: ops-w writes Setpoint (Good), Int32 BadTypeMismatch")

    # Sessions per user (each reads a drive's value, as a client does).
    opened = []
    for _ in range(max_sessions):
        c = Client(url)
        c.set_user("ops-r")
        c.set_password(read_token)
        await c.connect()
        ns = await c.get_namespace_index("urn:drivebus")
        await node(c, ns, "Drives/pump-1/Online").read_value()
        opened.append(c)
    extra = Client(url)
    extra.set_user("ops-r")
    extra.set_password(read_token)
    try:
        await extra.connect()
        await extra.disconnect()
        raise AssertionError(f"session {max_sessions + 1} of ops-r was accepted")
    except ua.UaStatusCodeError as e:
        code = ua.StatusCode(e.code).name
        assert code == "BadTooManySessions", f"session {max_sessions + 1} of ops-r: {code}"
    async with Client(url) as c:
        await c.get_namespace_index("urn:drivebus")
    await opened.pop().disconnect()
    again = Client(url)
    again.set_user("ops-r")
    again.set_password(read_token)
    async with again:
        await again.get_namespace_index("urn:drivebus")
    for c in opened:
        await c.disconnect()
    say(f"sessions: ops-r holds {max_sessions}, the next is BadTooManySessions, another user is not "
        "counted, a closed one frees its place")
    say("ALL OK")


def events_after(http, drive, after_id):
    url = f"{http}/api/events?kind=command&drive={drive}&limit=10000&after_id={after_id}"
    with urllib.request.urlopen(url, timeout=10) as r:
        return sorted(json.load(r), key=lambda e: e["id"])


async def order(url, http, token, drive, count):
    count = int(count)
    # The calls are answered one after another: time enough for all of them.
    c = Client(url, timeout=PATIENCE)
    c.set_user("demo")
    c.set_password(token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        d = node(c, ns, f"Drives/{drive}")
        method = {m: (await d.get_child(f"{ns}:{m}")).nodeid for m in ("SetSpeed", "Run", "Stop")}
        last = max([e["id"] for e in events_after(http, drive, 0)], default=0)

        plan = []
        for i in range(count):
            call = ua.CallMethodRequest()
            call.ObjectId = d.nodeid
            if i % 3 == 0:
                call.MethodId = method["SetSpeed"]
                hz = 10 + i % 40
                call.InputArguments = [ua.Variant(float(hz), ua.VariantType.Double)]
                plan.append((f"speed {hz} Hz", call))
            else:
                name = "Run" if i % 3 == 1 else "Stop"
                call.MethodId = method[name]
                call.InputArguments = []
                plan.append((name.lower(), call))
        # gather starts the calls in this order, each sent before the next starts, all on one
        # connection, none waiting for an answer.
        results = await asyncio.gather(*[c.uaclient.call([call]) for _, call in plan])
        codes = [r[0].StatusCode.name for r in results]
        assert all(code == "Good" for code in codes), f"pipelined calls: {codes}"
        sent = [action for action, _ in plan]

        async def all_there():
            found = events_after(http, drive, last)
            return found if len(found) >= count else None
        found = await until(f"{count} commands in the audit trail", all_there)
        done = [e["action"] for e in found]
        assert [e["result"] for e in found] == ["ok"] * count, f"results {[e['result'] for e in found]}"
        if done != sent:
            at = next(i for i, (a, b) in enumerate(zip(done, sent)) if a != b)
            raise AssertionError(f"the audit trail's command {at + 1} of {count} is {done[at]!r}, sent "
                                 f"{sent[at]!r}: trail {done[max(0, at - 3):at + 4]}, sent "
                                 f"{sent[max(0, at - 3):at + 4]}")
        say(f"order: {count} pipelined calls, the audit trail lists them in the order sent")

        speed = float(10 + max(i for i in range(count) if i % 3 == 0) % 40)
        running = [a for a in sent if a in ("run", "stop")][-1] == "run"

        async def settled():
            sp = await node(c, ns, f"Drives/{drive}/Setpoint").read_value()
            run = await node(c, ns, f"Drives/{drive}/Running").read_value()
            return abs(sp - speed) < 0.05 and run == running
        await until(f"{drive} at setpoint {speed} Hz, running {running}", settled)
        say(f"order: {drive} ends at setpoint {speed} Hz, running {running}, as last commanded")
    say("ALL OK")


async def template(url, token, drive):
    """A templated drive: browsed, its values read, commanded by method, a parameter read."""
    async with Client(url) as c:
        ns = await c.get_namespace_index("urn:drivebus")
        folder = await c.nodes.objects.get_child([f"{ns}:Drives"])
        found = [(await k.read_browse_name()).Name for k in await folder.get_children()]
        assert drive in found, f"Objects/Drives has {found}, not {drive}"
        say(f"browse: Objects/Drives has {drive}")

        async def good():
            v = await node(c, ns, f"Drives/{drive}/OutputFrequency").read_data_value(raise_on_bad_status=False)
            return v.StatusCode_.is_good() and v
        v = await until(f"{drive}/OutputFrequency Good", good)
        assert isinstance(v.Value.Value, float), f"OutputFrequency = {v.Value!r}"
        say(f"read: {drive}/OutputFrequency = {v.Value.Value} Hz, Good")

        # The template's [values]: a variable each in the drive's Values folder, with its unit.
        values = await node(c, ns, f"Drives/{drive}").get_child([f"{ns}:Values"])
        names = sorted([(await k.read_browse_name()).Name for k in await values.get_children()])
        assert names == ["dc_bus_v", "power_kw"], f"{drive}/Values has {names}"
        dc = node(c, ns, f"Drives/{drive}/Values/dc_bus_v")

        async def dc_good():
            v = await dc.read_data_value(raise_on_bad_status=False)
            return v.StatusCode_.is_good() and v
        v = await until(f"{drive}/Values/dc_bus_v Good", dc_good)
        assert isinstance(v.Value.Value, float) and 400.0 < v.Value.Value < 700.0, f"dc_bus_v = {v.Value!r}"
        assert v.SourceTimestamp is not None, "dc_bus_v has no source timestamp"
        eu = await (await dc.get_child(["0:EngineeringUnits"])).read_value()
        assert eu.DisplayName.Text == "V" and eu.UnitId == 0x564C54, f"dc_bus_v's EngineeringUnits: {eu}"
        code = await status_of(dc.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double))))
        assert code in ("BadNotWritable", "BadUserAccessDenied"), f"dc_bus_v written: {code}"
        say(f"values: {drive}/Values/dc_bus_v = {v.Value.Value} V, Good, EngineeringUnits V, read-only")

    c = Client(url)
    c.set_user("demo")
    c.set_password(token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        d = node(c, ns, f"Drives/{drive}")
        changes = Changes()
        sub = await c.create_subscription(100, changes)
        await sub.subscribe_data_change(node(c, ns, f"Drives/{drive}/Values/power_kw"))
        await d.call_method(f"{ns}:SetSpeed", ua.Variant(20.0, ua.VariantType.Double))
        await d.call_method(f"{ns}:Run")

        async def reached():
            hz = await node(c, ns, f"Drives/{drive}/OutputFrequency").read_value()
            return abs(hz - 20.0) <= 0.05 and hz
        await until(f"{drive} at 20 Hz after SetSpeed and Run", reached, 120)
        say(f"call: SetSpeed(20.0) and Run, {drive} turns at 20 Hz")

        async def powered():
            return [v for v in changes.values if isinstance(v, float) and v > 0.0]
        kw = await until(f"a notification of {drive}/Values/power_kw above 0", powered)
        say(f"subscription: {drive}/Values/power_kw notified {kw[-1]} kW while running")

        p = node(c, ns, f"Drives/{drive}/Parameters/P0.04")

        async def param():
            v = await p.read_data_value(raise_on_bad_status=False)
            return v.StatusCode_.is_good() and v
        v = await until(f"{drive}/Parameters/P0.04 Good", param)
        assert abs(v.Value.Value - 50.0) < 1e-9, f"P0.04 = {v.Value!r}"
        say(f"parameters: {drive}/Parameters/P0.04 = {v.Value.Value} Hz, by the template's name")
    say("ALL OK")


async def standby(url, token, drive, bus):
    c = Client(url)
    c.set_user("demo")
    c.set_password(token)
    async with c:
        ns = await c.get_namespace_index("urn:drivebus")
        for path in (f"Drives/{drive}/Source", f"Buses/{bus}/Role"):
            v = await node(c, ns, path).read_data_value(raise_on_bad_status=False)
            assert v.StatusCode_.is_good(), f"{path}: {v.StatusCode_.name}"
            assert v.Value.Value == "standby", f"{path} is {v.Value.Value!r}"
        say(f"standby: {drive}/Source and {bus}/Role read standby, Good")
        setpoint = node(c, ns, f"Drives/{drive}/Setpoint")
        code = await status_of(setpoint.write_value(ua.DataValue(ua.Variant(20.0, ua.VariantType.Double))))
        assert code == "BadInvalidState", f"Setpoint written on a standby: {code}"
        code = await status_of(node(c, ns, f"Drives/{drive}").call_method(f"{ns}:Run"))
        assert code == "BadInvalidState", f"Run called on a standby: {code}"
        say("standby: a Setpoint write and a Run call are Bad_InvalidState")
    say("ALL OK")


def monitored_items(http):
    """drivebus_opcua_monitored_items in GET /metrics (None while it is not there)."""
    with urllib.request.urlopen(f"{http}/metrics", timeout=10) as r:
        text = r.read().decode()
    for line in text.splitlines():
        if line.startswith("drivebus_opcua_monitored_items "):
            return int(line.split()[1])
    return None


async def metric_is(http, n, what):
    async def probe():
        return monitored_items(http) == n
    try:
        await until(what, probe)
    except AssertionError:
        raise AssertionError(f"{what}: drivebus_opcua_monitored_items is {monitored_items(http)}, not {n}")
    say(f"metric: {what}: drivebus_opcua_monitored_items {n}")


async def subscribe_items(c, drives, params):
    """Subscribes (one subscription of `params`) to three variables of each drive and to the
    Server object's events; returns the subscription and the number of items."""
    ns = await c.get_namespace_index("urn:drivebus")
    sub = await c.create_subscription(params, Changes())
    variables = [node(c, ns, f"Drives/{d}/{n}") for d in drives for n in ("OutputFrequency", "Current", "Running")]
    handles = await sub.subscribe_data_change(variables)
    assert all(isinstance(h, int) for h in handles), f"data items refused: {handles}"
    await sub.subscribe_events(c.nodes.server)
    return sub, len(variables) + 1


async def items(url, http, drives):
    drives = drives.split(",")
    await metric_is(http, 0, "no client yet")

    async with Client(url) as c:
        sub, k = await subscribe_items(c, drives, 100)
        await metric_is(http, k, f"a client subscribed to {k} items")
        await sub.delete()
        await metric_is(http, 0, "the client deleted its subscription")

    c = Client(url)
    await c.connect()
    _, k = await subscribe_items(c, drives, 100)
    await metric_is(http, k, f"another client subscribed to {k} items")
    await c.disconnect()
    await metric_is(http, 0, "that client closed its session")

    # A client that vanishes: its subscription (publishing every 50 ms, a keep-alive every
    # publish, so a lifetime of 3 publishing intervals) expires once no publish request is left.
    c = Client(url)
    await c.connect()
    params = ua.CreateSubscriptionParameters(
        RequestedPublishingInterval=50, RequestedLifetimeCount=3, RequestedMaxKeepAliveCount=1,
        MaxNotificationsPerPublish=0, PublishingEnabled=True, Priority=0)
    _, k = await subscribe_items(c, drives, params)
    await metric_is(http, k, f"a third client subscribed to {k} items")
    c.disconnect_socket()
    await metric_is(http, 0, "that client vanished (its subscription expired)")
    say("ALL OK")


# Each mode: its coroutine and how many arguments it takes after the mode's name.
MODES = {
    "trust": (trust, 6),
    "history": (history, 3),
    "big": (big, 2),
    "order": (order, 5),
    "template": (template, 3),
    "standby": (standby, 4),
    "items": (items, 3),
    "check": (check, 7),
}


def main():
    if len(sys.argv) >= 3 and sys.argv[1] == "mkcert":
        asyncio.run(mkcert(sys.argv[2]))
        return
    mode = MODES.get(sys.argv[1]) if len(sys.argv) >= 2 else None
    if mode is None or len(sys.argv) != 2 + mode[1]:
        print(__doc__)
        sys.exit(3)
    try:
        asyncio.run(mode[0](*sys.argv[2:]))
    except AssertionError as e:
        print(f"FAILED: {e}", flush=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
