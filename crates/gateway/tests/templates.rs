//! Templated drives in the gateway: `templates = [...]` in the configuration, `family = "<kind>"`
//! on a virtual bus (the simulator runs the template), and the drives polled, commanded and
//! shown like built-in ones: the views, the HTTP API, the unified Modbus TCP map and parameter
//! reads by the template's names.

mod support;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::connect_info::MockConnectInfo;
use axum::http::Request;
use drivebus_gateway::core::{Command, Gateway};
use drivebus_gateway::GatewayConfig;
use http_body_util::BodyExt;
use support::wait_for;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tower::ServiceExt;

fn gateway() -> Arc<Gateway> {
    let text = "templates = [\"bits.toml\"]\n[store]\ndisabled = true\n[http]\nanonymous_read = true\n\
         [[bus]]\nname = \"a\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
         [[bus.drive]]\nname = \"fan\"\nfamily = \"gw-bits\"\naddress = 1\npoll_ms = 100\n\
         [[bus.drive]]\nname = \"pump\"\nfamily = \"generic-2000h\"\naddress = 2\npoll_ms = 100\n";
    let (dir, c) = support::with_bits_template("gw-templates", text);
    // The template's path is taken from the configuration's folder.
    assert_eq!(c.templates, [dir.join("bits.toml")]);
    Gateway::start(c, None).unwrap()
}

/// The unified map's input registers 0..10 of `unit`, over an in-process Modbus TCP connection.
async fn input_registers(gw: &Arc<Gateway>, unit: u8) -> Vec<u16> {
    let (mut client, server) = tokio::io::duplex(1024);
    let peer: SocketAddr = "127.0.0.1:5020".parse().unwrap();
    tokio::spawn(drivebus_gateway::modbus_tcp::serve_stream(gw.clone(), server, peer));
    client.write_all(&[0, 1, 0, 0, 0, 6, unit, 0x04, 0, 0, 0, 10]).await.unwrap();
    let mut reply = [0u8; 9 + 20];
    client.read_exact(&mut reply).await.unwrap();
    assert_eq!(&reply[7..9], [0x04, 20], "{reply:?}");
    reply[9..].chunks(2).map(|w| u16::from_be_bytes([w[0], w[1]])).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn templated_drives_are_polled_commanded_and_shown_like_any_drive() {
    let gw = gateway();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("both drives online", Duration::from_secs(20), || {
        view("fan").online == Some(true) && view("pump").online == Some(true)
    })
    .await;
    assert_eq!(view("fan").family, "gw-bits");
    assert_eq!(view("pump").family, "generic-2000h");

    gw.command("fan", Command::Speed(30.0), "test").await.expect("speed");
    gw.command("fan", Command::Run, "test").await.expect("run");
    gw.command("pump", Command::Speed(20.0), "test").await.expect("speed");
    gw.command("pump", Command::Run, "test").await.expect("run");
    wait_for("fan at 30 Hz and pump at 20 Hz", Duration::from_secs(60), || {
        view("fan").output_hz == Some(30.0) && view("pump").output_hz == Some(20.0)
    })
    .await;
    assert_eq!(view("fan").running, Some(true));
    let acc = gw.read_param("fan", "acc", "test").await.expect("acc");
    assert_eq!(acc.raw, 100, "10.0 s at 0.1 s");

    // The HTTP API shows them as any drive.
    let app = drivebus_gateway::http::router(gw.clone())
        .layer(MockConnectInfo(SocketAddr::from(([127, 0, 0, 1], 40000))));
    let r = app.oneshot(Request::get("/api/drives/fan").body(Body::empty()).unwrap()).await.unwrap();
    let body = r.into_body().collect().await.unwrap().to_bytes();
    let json: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(json["family"], "gw-bits", "{json}");
    assert_eq!(json["output_hz"], 30.0, "{json}");
    // Its named values, with their units.
    assert_eq!(json["values"]["dc_bus_v"]["unit"], "V", "{json}");
    let dc = json["values"]["dc_bus_v"]["value"].as_f64().unwrap_or_default();
    assert!((400.0..700.0).contains(&dc), "the simulated DC bus: {json}");
    assert_eq!(json["values"]["power_kw"]["unit"], "kW", "{json}");

    // The unified Modbus TCP map: status word running, 30.00 Hz, family 5 (a template kind).
    let unit = gw.drive("fan").unwrap().config.unit_id;
    let regs = input_registers(&gw, unit).await;
    assert_eq!(regs[0] & 1, 1, "running: {regs:?}");
    assert_eq!(regs[1], 3000, "{regs:?}");
    assert_eq!(regs[8], 5, "a template kind: {regs:?}");

    gw.command("fan", Command::Stop, "test").await.expect("stop");
    wait_for("fan stopped", Duration::from_secs(60), || view("fan").running == Some(false)).await;
    // A template file that cannot be read is the configuration's error, with its line.
    let errors = GatewayConfig::from_toml("t.toml", "templates = [\"/nonexistent/x.toml\"]\n")
        .unwrap_err()
        .to_string();
    assert!(
        errors.starts_with("t.toml:1: field `templates`: /nonexistent/x.toml: cannot read it"),
        "{errors}"
    );
}

/// Backup, diff (a dry-run restore) and restore of a templated drive: its parameters by the
/// template's names, the file read back as the same kind, a changed parameter found and written
/// back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_templated_drive_is_backed_up_compared_and_restored() {
    use drivebus_drive::backup::Backup;
    use drivebus_gateway::core::RestoreOptions;
    let gw = gateway();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("fan online", Duration::from_secs(20), || view("fan").online == Some(true)).await;
    let backup = gw.backup("fan", "test").await.expect("backup");
    let text = backup.to_text();
    assert!(text.contains("gw-bits") && text.contains("acc"), "{text}");
    let file = Backup::parse(&text).expect("the file reads back");
    assert_eq!(file, backup);
    // acc changed on the drive: the diff finds it, the restore writes the file's value back.
    let set = Command::SetParamRaw { name: "acc".into(), raw: 250, shown: "25.0 s".into(), eeprom: true };
    gw.command("fan", set, "test").await.expect("set acc");
    let dry = RestoreOptions { dry_run: true, only: None, include_comm: false };
    let rows = gw.restore("fan", &file, &dry, "test", "test").await.expect("diff");
    let found: Vec<(&str, i64, i64)> =
        rows.iter().map(|r| (r.name.as_str(), r.drive.raw, r.file.raw)).collect();
    assert_eq!(found, [("acc", 250, 100)]);
    assert_eq!(gw.read_param("fan", "acc", "test").await.unwrap().raw, 250, "a dry run writes nothing");
    let apply = RestoreOptions { dry_run: false, ..dry.clone() };
    let rows = gw.restore("fan", &file, &apply, "test", "test").await.expect("restore");
    assert_eq!(rows[0].result, Some("ok"), "{:?}", rows[0].error);
    assert_eq!(gw.read_param("fan", "acc", "test").await.unwrap().raw, 100);
    // A backup of another kind is refused.
    let other = gw.backup("pump", "test").await.expect("the pump's backup");
    let e = gw.restore("fan", &other, &dry, "test", "test").await.expect_err("another kind");
    assert!(e.to_string().contains("generic-2000h"), "{e}");
}

/// GET `path` on the gateway's HTTP API (anonymous reads allowed): the JSON answer.
async fn get_json(gw: &Arc<Gateway>, path: &str) -> serde_json::Value {
    let app = drivebus_gateway::http::router(gw.clone())
        .layer(MockConnectInfo(SocketAddr::from(([127, 0, 0, 1], 40000))));
    let r = app.oneshot(Request::get(path).body(Body::empty()).unwrap()).await.unwrap();
    let body = r.into_body().collect().await.unwrap().to_bytes();
    serde_json::from_slice(&body).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shipped_template_shows_its_fault_history() {
    // abb-acs550 is shipped: no `templates = [...]` line.
    let text = "[store]\ndisabled = true\n[http]\nanonymous_read = true\n\
         [[bus]]\nname = \"b\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\n\
         [[bus.drive]]\nname = \"acs\"\nfamily = \"abb-acs550\"\naddress = 1\npoll_ms = 100\n";
    let gw =
        Gateway::start(GatewayConfig::from_toml("plant.toml", text).unwrap_or_else(|e| panic!("{e}")), None)
            .unwrap();
    let view = |id: &str| gw.drive_view(&gw.drive(id).unwrap());
    wait_for("acs online", Duration::from_secs(20), || view("acs").online == Some(true)).await;
    let json = get_json(&gw, "/api/drives/acs").await;
    // Its template gives no named values (their scales were not confirmed): none shown.
    assert_eq!(json["values"], serde_json::Value::Null, "{json}");

    // A trip, then a reset: 0401 keeps the code, the drive is no longer tripped, the history has it.
    let bus = gw.buses().iter().find(|b| b.config.name == "b").unwrap().clone();
    {
        let mut line = bus.line.as_ref().unwrap().lock().unwrap();
        let port = (0..=line.devices()).find(|&p| line.drive(p).is_some()).unwrap();
        line.drive_mut(port).unwrap().core_mut().model.trip_now(drivebus_sim::model::Trip::OverCurrent);
    }
    wait_for("the trip seen", Duration::from_secs(20), || view("acs").fault.is_some()).await;
    assert_eq!(view("acs").fault.unwrap().text, "over-current (OVERCURRENT)");
    gw.command("acs", Command::Reset, "test").await.expect("reset");
    wait_for("the fault cleared", Duration::from_secs(20), || view("acs").fault.is_none()).await;
    let trips = get_json(&gw, "/api/drives/acs/trips").await;
    assert_eq!(trips["current"], serde_json::Value::Null, "{trips}");
    assert_eq!(trips["history"][0]["code"], 1, "{trips}");
    assert_eq!(trips["history"][0]["text"], "over-current (OVERCURRENT)", "{trips}");
    assert!(trips["source"].as_str().is_some_and(|s| s.contains("0401, 0412, 0413")), "{trips}");
}
