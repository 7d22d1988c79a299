#!/usr/bin/env node
// A second OPC UA client stack nobody here wrote (node-opcua, npm, pinned in package.json) against
// `drivebus serve`, beside the asyncua client (../opcua_client.py). crates/cli/tests/opcua_node.rs
// runs it.
//
//     opcua_client.js mkcert DIR
//         makes the client's certificate and key in DIR/pki (node-opcua's own store) and writes
//         the certificate as DER to DIR/client.der, for [opcua] trusted_clients.
//     opcua_client.js check URL TOKEN DRIVES OFFLINE TRIPPED CONTROL DIR SERVERCERT
//         URL         opc.tcp://HOST:PORT of the gateway
//         TOKEN       the write token of user "demo"
//         DRIVES      every drive id, comma-separated
//         OFFLINE     a drive on a port that does not exist
//         TRIPPED     a drive on a `drivebus simulate` process, tripped and silenced through CONTROL
//         CONTROL     http://HOST:PORT of that simulator's control interface
//         DIR         the folder given to mkcert
//         SERVERCERT  the gateway's certificate (DER), trusted by this client
//
// Prints one line per check ("ok   name: what was seen" or "FAIL name: why") and, when every check
// held, "ALL OK"; exits 1 when one failed. Every check runs even when an earlier one failed.

"use strict";

const fs = require("fs");
const path = require("path");
const opcua = require("node-opcua");

const {
  AttributeIds,
  BrowseDirection,
  DataChangeFilter,
  DataChangeTrigger,
  DataType,
  DeadbandType,
  MessageSecurityMode,
  OPCUACertificateManager,
  OPCUAClient,
  SecurityPolicy,
  StatusCodes,
  TimestampsToReturn,
  UserTokenType,
  Variant,
  constructEventFilter,
  makeBrowsePath,
} = opcua;

const APPLICATION_URI = "urn:drivebus:test:node-opcua";
const PATIENCE_MS = 20000;
const VARIABLES = ["OutputFrequency", "Setpoint", "Current", "Running", "Direction", "FaultCode",
  "FaultText", "Online", "AgeMs", "ErrorRate"];

const failures = [];

function say(line) {
  process.stdout.write(line + "\n");
}

// Runs one check: `probe` returns what was seen or throws why not.
async function check(name, probe) {
  try {
    say(`ok   ${name}: ${await probe()}`);
  } catch (e) {
    failures.push(name);
    say(`FAIL ${name}: ${(e && (e.message || e.stack)) || e}`);
  }
}

function expect(cond, why) {
  if (!cond) {
    throw new Error(why);
  }
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Waits (generously) until `probe()` gives a true value, which it returns.
async function until(what, probe, patience = PATIENCE_MS) {
  const deadline = Date.now() + patience;
  let last;
  while (Date.now() < deadline) {
    last = await probe();
    if (last) {
      return last;
    }
    await sleep(100);
  }
  throw new Error(`${what}: still ${JSON.stringify(last)} after ${patience / 1000} s`);
}

async function post(url, body) {
  const r = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  expect(r.ok, `POST ${url}: ${r.status}`);
}

function pemToDer(pem) {
  const b64 = pem.replace(/-----[^-]+-----/g, "").replace(/\s+/g, "");
  return Buffer.from(b64, "base64");
}

async function certificateManager(dir) {
  const cm = new OPCUACertificateManager({ rootFolder: path.join(dir, "pki"), automaticallyAcceptUnknownCertificate: false });
  await cm.initialize();
  return cm;
}

async function mkcert(dir) {
  fs.mkdirSync(dir, { recursive: true });
  const cm = await certificateManager(dir);
  const pem = path.join(cm.rootDir, "own/certs/self_signed_certificate.pem");
  await cm.createSelfSignedCertificate({
    applicationUri: APPLICATION_URI,
    subject: "/CN=drivebus node-opcua test/O=drivebus tests",
    dns: ["localhost"],
    startDate: new Date(Date.now() - 24 * 3600 * 1000),
    validity: 30,
  });
  fs.writeFileSync(path.join(dir, "client.der"), pemToDer(fs.readFileSync(pem, "utf8")));
  say(`certificate ${path.join(dir, "client.der")}`);
}

function client(cm, dir, secure) {
  const options = {
    applicationName: "drivebus node-opcua test",
    applicationUri: APPLICATION_URI,
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 1, initialDelay: 200, maxDelay: 1000 },
    clientCertificateManager: cm,
    certificateFile: path.join(cm.rootDir, "own/certs/self_signed_certificate.pem"),
    privateKeyFile: path.join(cm.rootDir, "own/private/private_key.pem"),
    securityMode: MessageSecurityMode.None,
    securityPolicy: SecurityPolicy.None,
  };
  if (secure) {
    options.securityMode = MessageSecurityMode.SignAndEncrypt;
    options.securityPolicy = SecurityPolicy.Basic256Sha256;
  }
  return OPCUAClient.create(options);
}

// How many notifications repeat the previous one's value and status (a source-timestamp-only change).
const repeats = (seen) => seen.filter((v, i) => i > 0 && v.value.value === seen[i - 1].value.value
  && v.statusCode === seen[i - 1].statusCode).length;

// The status code's name of a call's or write's answer.
const named = (code) => (code && code.name) || String(code);

async function run(url, token, drives, offline, tripped, control, dir, serverCert) {
  drives = drives.split(",");
  const online = drives.filter((d) => d !== offline);
  const cm = await certificateManager(dir);
  await cm.trustCertificate(fs.readFileSync(serverCert));

  // Session A: anonymous, endpoint None: browse, read, subscribe, events.
  const plain = client(cm, dir, false);
  await plain.connect(url);
  const a = await plain.createSession();
  const ns = (await a.readNamespaceArray()).indexOf("urn:drivebus");
  expect(ns > 0, "namespace urn:drivebus missing");
  const id = (p) => `ns=${ns};s=${p}`;
  const read = (p, attributeId = AttributeIds.Value) => a.read({ nodeId: id(p), attributeId }, 0);

  await check("browse", async () => {
    const r = await a.browse({
      nodeId: id("Drives"),
      browseDirection: BrowseDirection.Forward,
      referenceTypeId: "HierarchicalReferences",
      includeSubtypes: true,
      resultMask: 63,
    });
    expect(r.statusCode.isGood(), `browse Drives: ${r.statusCode.name}`);
    const found = r.references.map((x) => x.browseName.name).sort();
    expect(JSON.stringify(found) === JSON.stringify([...drives].sort()), `Objects/Drives has ${found}`);
    const ofType = r.references.every((x) => x.browseName.namespaceIndex === ns);
    expect(ofType, "a drive's browse name is outside urn:drivebus");
    return `Objects/Drives has all ${found.length} drives, browse names in urn:drivebus`;
  });

  await check("read", async () => {
    for (const d of online) {
      await until(`every variable of ${d} Good`, async () => {
        const values = await a.read(VARIABLES.map((v) => ({ nodeId: id(`Drives/${d}/${v}`), attributeId: AttributeIds.Value })), 0);
        return values.every((v) => v.statusCode.isGood()) && values;
      });
    }
    const values = await a.read(VARIABLES.map((v) => ({ nodeId: id(`Drives/${online[0]}/${v}`), attributeId: AttributeIds.Value })), 0);
    for (const [n, v] of VARIABLES.map((n, i) => [n, values[i]])) {
      expect(v.sourceTimestamp && v.serverTimestamp, `${online[0]}/${n} lacks a timestamp: ${v.toString()}`);
      expect(v.sourceTimestamp.getTime() <= v.serverTimestamp.getTime() + 5, `${online[0]}/${n}: source after server timestamp`);
    }
    const types = values.map((v) => DataType[v.value.dataType]).join(" ");
    return `every variable of ${online.length} drives Good, with source and server timestamps (${types})`;
  });

  await check("read offline", async () => {
    const v = await until(`${offline} BadNoCommunication`, async () => {
      const v = await read(`Drives/${offline}/OutputFrequency`);
      return v.statusCode === StatusCodes.BadNoCommunication && v;
    });
    const on = await read(`Drives/${offline}/Online`);
    expect(on.value.value === false && on.statusCode.isGood(), `${offline}/Online ${on.toString()}`);
    return `${offline}: values ${v.statusCode.name}, Online false (Good)`;
  });

  // The source timestamp of a value that does not change follows the polls that confirm it, and
  // AgeMs is its age at AgeMs's server timestamp (docs/opcua.md, "Values, timestamps and status").
  await check("source timestamp", async () => {
    const d = online[0];
    const pair = () => a.read([id(`Drives/${d}/FaultCode`), id(`Drives/${d}/AgeMs`)].map((nodeId) => ({ nodeId, attributeId: AttributeIds.Value })), 0);
    const [first] = await pair();
    const [later, age] = await until(`${d}/FaultCode's source timestamp moving on with the polls`, async () => {
      const [v, age] = await pair();
      return v.value.value === first.value.value && v.sourceTimestamp > first.sourceTimestamp && [v, age];
    }, 5000);
    const gap = age.serverTimestamp - later.sourceTimestamp;
    expect(Math.abs(gap - age.value.value) <= 20,
      `AgeMs ${age.value.value} ms, but its server timestamp is ${gap} ms after FaultCode's source timestamp`);
    return `FaultCode ${first.value.value} confirmed again after ${later.sourceTimestamp - first.sourceTimestamp} ms; AgeMs ${age.value.value} = server timestamp - source timestamp`;
  });

  await check("engineering units", async () => {
    const unit = async (v) => {
      const r = await a.translateBrowsePath(makeBrowsePath("ObjectsFolder", `/${ns}:Drives/${ns}:${online[0]}/${ns}:${v}.EngineeringUnits`));
      expect(r.statusCode.isGood(), `${v}/EngineeringUnits: ${r.statusCode.name}`);
      const eu = (await a.read({ nodeId: r.targets[0].targetId, attributeId: AttributeIds.Value })).value.value;
      return `${eu.displayName.text} (${eu.unitId})`;
    };
    const got = { OutputFrequency: await unit("OutputFrequency"), Current: await unit("Current"), AgeMs: await unit("AgeMs") };
    // UNECE codes as OPC UA numbers them: HTZ, AMP, C26.
    expect(got.OutputFrequency === "Hz (4740186)", `OutputFrequency ${got.OutputFrequency}`);
    expect(got.Current === "A (4279632)", `Current ${got.Current}`);
    expect(got.AgeMs === "ms (4403766)", `AgeMs ${got.AgeMs}`);
    const r = await a.translateBrowsePath(makeBrowsePath("ObjectsFolder", `/${ns}:Drives/${ns}:${online[0]}/${ns}:ErrorRate.EURange`));
    const range = (await a.read({ nodeId: r.targets[0].targetId, attributeId: AttributeIds.Value })).value.value;
    expect(range.low === 0 && range.high === 1, `ErrorRate EURange ${JSON.stringify(range)}`);
    return `OutputFrequency ${got.OutputFrequency}, Current ${got.Current}, AgeMs ${got.AgeMs}, ErrorRate EURange 0..1`;
  });

  await check("translate browse paths", async () => {
    const [hit, miss] = await a.translateBrowsePath([
      makeBrowsePath("ObjectsFolder", `/${ns}:Drives/${ns}:pump-1/${ns}:OutputFrequency`),
      makeBrowsePath("ObjectsFolder", `/${ns}:Drives/${ns}:pump-1/${ns}:NoSuchVariable`),
    ]);
    expect(hit.statusCode.isGood() && hit.targets[0].targetId.toString() === id("Drives/pump-1/OutputFrequency"),
      `Drives/pump-1/OutputFrequency: ${hit.toString()}`);
    expect(miss.statusCode === StatusCodes.BadNoMatch, `a missing path: ${miss.statusCode.name}`);
    return `Objects/Drives/pump-1/OutputFrequency is ${hit.targets[0].targetId.toString()}, a missing name BadNoMatch`;
  });

  // One subscription for values and events; every DataChangeNotification is kept by client
  // handle, so one for an event item is seen whatever node-opcua makes of it.
  const sub = await a.createSubscription2({
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20,
    maxNotificationsPerPublish: 0,
    publishingEnabled: true,
    priority: 1,
  });
  const dataChanges = [];
  sub.on("raw_notification", (msg) => {
    for (const n of msg.notificationData || []) {
      if (n.schema && n.schema.name === "DataChangeNotification") {
        for (const m of n.monitoredItems || []) {
          dataChanges.push({ handle: m.clientHandle, value: m.value });
        }
      }
    }
  });
  const watch = async (p, filter) => {
    const seen = [];
    const item = await sub.monitor({ nodeId: id(p), attributeId: AttributeIds.Value },
      { samplingInterval: 0, queueSize: 100, discardOldest: true, filter }, TimestampsToReturn.Both);
    item.on("changed", (dv) => seen.push(dv));
    return seen;
  };
  const eventFields = ["EventId", "SourceName", "Message", "Severity"];
  const watchEvents = async (nodeId) => {
    const seen = [];
    const item = await sub.monitor({ nodeId, attributeId: AttributeIds.EventNotifier },
      { samplingInterval: 0, queueSize: 100, discardOldest: true, filter: constructEventFilter(eventFields) }, TimestampsToReturn.Both);
    item.on("changed", (fields) => seen.push({ source: fields[1].value, message: fields[2].value.text, severity: fields[3].value }));
    return { seen, handle: item.monitoringParameters.clientHandle };
  };
  const hz = await watch("Drives/pump-1/OutputFrequency");
  const serverEvents = await watchEvents("ns=0;i=2253");
  const folderEvents = await watchEvents(id("Drives"));
  const trippedFault = await watch(`Drives/${tripped}/FaultCode`);
  const steady = await watch("Drives/pump-2/FaultCode");
  const everyPoll = await watch("Drives/pump-2/FaultCode", new DataChangeFilter({
    trigger: DataChangeTrigger.StatusValueTimestamp, deadbandType: DeadbandType.None, deadbandValue: 0,
  }));

  // Session B: Basic256Sha256 SignAndEncrypt with the trusted client certificate, user demo.
  const secure = client(cm, dir, true);
  // An anonymous session on the same secure channel too: refusals for want of a role, not of security.
  let b, anonymous;
  await check("SignAndEncrypt session", async () => {
    await secure.connect(url);
    b = await secure.createSession({ type: UserTokenType.UserName, userName: "demo", password: token });
    anonymous = await secure.createSession();
    const running = await b.read({ nodeId: id("Drives/pump-1/Online"), attributeId: AttributeIds.Value });
    expect(running.statusCode.isGood(), `read over SignAndEncrypt: ${running.toString()}`);
    return `Basic256Sha256 SignAndEncrypt with the client certificate of [opcua] trusted_clients, user demo; pump-1 Online ${running.value.value}`;
  });
  const call = (s, drive, method, args = []) => s.call({ objectId: id(`Drives/${drive}`), methodId: id(`Drives/${drive}/${method}`), inputArguments: args });
  const dbl = (x) => new Variant({ dataType: DataType.Double, value: x });

  await check("method calls", async () => {
    expect(b, "no SignAndEncrypt session");
    const speed = await call(b, "pump-1", "SetSpeed", [dbl(40)]);
    const go = await call(b, "pump-1", "Run");
    expect(speed.statusCode.isGood() && go.statusCode.isGood(), `SetSpeed ${named(speed.statusCode)}, Run ${named(go.statusCode)}`);
    return "SetSpeed(40.0) Good, Run() Good on pump-1 as user demo";
  });

  await check("subscription", async () => {
    await until("OutputFrequency notifications reaching 40 Hz", async () => hz.some((v) => Math.abs(v.value.value - 40) <= 0.1), 60000);
    const ramp = hz.map((v) => v.value.value);
    expect(new Set(ramp).size > 3, `too few changes while ramping: ${ramp}`);
    expect(repeats(hz) === 0, `a value notified twice in a row with the same status: ${hz.map((v) => `${v.value.value} ${v.statusCode.name}`)}`);
    return `${ramp.length} changes while pump-1 ramped to 40 Hz, none repeated`;
  });

  await check("subscription triggers", async () => {
    // The default trigger (StatusValue): a poll that only confirms the value notifies nothing;
    // StatusValueTimestamp: every poll that confirms it does.
    await until("StatusValueTimestamp notifications for each confirming poll", async () => everyPoll.length >= 4, 10000);
    const stamps = everyPoll.map((v) => v.sourceTimestamp.getTime());
    expect(stamps.every((t, i) => i === 0 || t > stamps[i - 1]), `source timestamps not increasing: ${stamps}`);
    expect(steady.length >= 1 && repeats(steady) === 0,
      `the default trigger notified a poll that changed neither value nor status: ${steady.map((v) => v.toString())}`);
    return `pump-2/FaultCode: default trigger ${steady.length} notification(s), none for a confirming poll; `
      + `StatusValueTimestamp ${everyPoll.length}, source timestamps ${stamps[1] - stamps[0]}, ${stamps[2] - stamps[1]}, ... ms apart`;
  });

  await check("method refusals", async () => {
    const anon = await call(anonymous, "pump-1", "SetSpeed", [dbl(30)]);
    const high = await call(b, "pump-1", "SetSpeed", [dbl(1000)]);
    const int = await call(b, "pump-1", "SetSpeed", [new Variant({ dataType: DataType.Int32, value: 30 })]);
    const none = await call(b, "pump-1", "SetSpeed", []);
    const locked = await call(b, "pump-3", "Run");
    const got = `anonymous ${named(anon.statusCode)}, 1000 Hz ${named(high.statusCode)}, Int32 ${named(int.statusCode)} `
      + `[${(int.inputArgumentResults || []).map(named)}], no argument ${named(none.statusCode)}, locked pump-3 ${named(locked.statusCode)}`;
    expect(anon.statusCode === StatusCodes.BadUserAccessDenied, got);
    expect(high.statusCode === StatusCodes.BadOutOfRange, got);
    expect(int.statusCode === StatusCodes.BadInvalidArgument && int.inputArgumentResults[0] === StatusCodes.BadTypeMismatch, got);
    expect(none.statusCode === StatusCodes.BadArgumentsMissing, got);
    expect(locked.statusCode === StatusCodes.BadNotWritable, got);
    return got;
  });

  await check("writes", async () => {
    const write = (s, p, dataType, value) => s.write({ nodeId: id(p), attributeId: AttributeIds.Value, value: { value: new Variant({ dataType, value }) } });
    const int = await write(b, "Drives/pump-1/Setpoint", DataType.Int32, 35);
    const str = await write(b, "Drives/pump-1/Setpoint", DataType.String, "35");
    const ro = await write(b, "Drives/pump-1/OutputFrequency", DataType.Double, 35);
    const anon = await write(anonymous, "Drives/pump-1/Setpoint", DataType.Double, 35);
    const float = await write(b, "Drives/pump-1/Setpoint", DataType.Float, 36);
    const ok = await write(b, "Drives/pump-1/Setpoint", DataType.Double, 35);
    const got = `Int32 ${named(int)}, String ${named(str)}, OutputFrequency ${named(ro)}, anonymous ${named(anon)}, Float ${named(float)}, Double ${named(ok)}`;
    expect(int === StatusCodes.BadTypeMismatch && str === StatusCodes.BadTypeMismatch, got);
    expect(ro === StatusCodes.BadNotWritable && anon === StatusCodes.BadUserAccessDenied, got);
    expect(float.isGood() && ok.isGood(), got);
    const sp = await until("Setpoint reading 35 Hz", async () => {
      const v = await read("Drives/pump-1/Setpoint");
      return Math.abs(v.value.value - 35) < 0.01 && v;
    });
    return `${got}; Setpoint reads ${sp.value.value} Hz`;
  });

  await check("events", async () => {
    await post(`${control}/drives/1`, { trip: "over-current" });
    const trip = (e) => e.source === tripped && /trip/i.test(e.message);
    const onServer = await until(`a trip event from ${tripped} on the Server object`, async () => serverEvents.seen.find(trip));
    const onFolder = await until(`a trip event from ${tripped} on the Drives folder`, async () => folderEvents.seen.find(trip));
    expect(onServer.severity === 800 && onFolder.severity === 800, `severity ${onServer.severity}`);
    return `"${onServer.message}" (severity ${onServer.severity}) on the Server object and the Drives folder`;
  });

  await check("status without a value change", async () => {
    // The drive stops answering: its fault code stays, its status turns Bad; a subscription
    // without a filter (trigger StatusValue) is told.
    await until(`${tripped}/FaultCode showing the trip`, async () => trippedFault.some((v) => v.value.value !== 0));
    await post(`${control}/drives/1`, { silent: true });
    const bad = await until(`${tripped}/FaultCode notified BadNoCommunication`,
      async () => trippedFault.find((v) => v.statusCode === StatusCodes.BadNoCommunication), 30000);
    const before = trippedFault[trippedFault.indexOf(bad) - 1];
    expect(before && before.value.value === bad.value.value, `the value changed too: ${before} -> ${bad}`);
    const offlineEvent = await until(`an offline event from ${tripped}`, async () => serverEvents.seen.find((e) => e.source === tripped && e.severity === 600));
    return `FaultCode ${bad.value.value} Good -> ${bad.statusCode.name}; event "${offlineEvent.message}"`;
  });

  await check("no data change for event items", async () => {
    const handles = [serverEvents.handle, folderEvents.handle];
    const stray = dataChanges.filter((d) => handles.includes(d.handle));
    expect(stray.length === 0, `${stray.length} DataChangeNotification(s) for event items: ${stray.map((d) => d.value.toString().replace(/\s+/g, " "))}`);
    return `${serverEvents.seen.length + folderEvents.seen.length} events and no DataChangeNotification on the Server object's and the Drives folder's event items`;
  });

  await sub.terminate();
  await a.close();
  await plain.disconnect();
  for (const s of [b, anonymous]) {
    if (s) {
      await s.close();
    }
  }
  await secure.disconnect();
}

async function main() {
  const [cmd, ...args] = process.argv.slice(2);
  if (cmd === "mkcert" && args.length === 1) {
    await mkcert(args[0]);
  } else if (cmd === "check" && args.length === 8) {
    try {
      await run(...args);
    } catch (e) {
      failures.push("setup");
      say(`FAIL setup: ${e && e.stack ? e.stack : e}`);
    }
    say(failures.length ? `FAILED: ${failures.join(", ")}` : "ALL OK");
    process.exit(failures.length ? 1 : 0);
  } else {
    say(fs.readFileSync(__filename, "utf8").split("\n").slice(1, 19).join("\n"));
    process.exit(3);
  }
}

main().catch((e) => {
  say(`FAIL: ${e && e.stack ? e.stack : e}`);
  process.exit(1);
});
