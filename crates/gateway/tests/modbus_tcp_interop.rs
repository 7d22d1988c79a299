//! Interop with Modbus TCP clients nobody here wrote: pymodbus (PyPI) and mbpoll (Debian) talk
//! to the gateway's server running the demo on 127.0.0.1.
//!
//! A plain `cargo test` lists these tests as ignored (`cargo test -- --ignored` runs them).
//! `.ci/install-witnesses.sh` installs both and CI sets `DRIVEBUS_REQUIRE_INTEROP=1`, so there a
//! missing witness is a failure.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use drivebus_gateway::{Gateway, GatewayConfig};
use tokio::net::TcpListener;

#[path = "../../../tests/interop/witness.rs"]
mod witness;
use witness::witness;

fn has_pymodbus() -> bool {
    witness::python_has("pymodbus")
}

fn has_mbpoll() -> bool {
    witness::runs("mbpoll", &["-V"], false)
}

async fn serve_demo() -> SocketAddr {
    let gw = Gateway::start(GatewayConfig::demo(), None).unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(drivebus_gateway::modbus_tcp::serve(gw, listener));
    addr
}

/// Runs a witness off the runtime's workers; its stdout, or the failure with its stderr.
async fn run(mut cmd: Command) -> Result<String, String> {
    let out = tokio::task::spawn_blocking(move || cmd.output()).await.unwrap().map_err(|e| e.to_string())?;
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    if out.status.success() {
        Ok(stdout)
    } else {
        Err(format!("{}\n{stdout}{}", out.status, String::from_utf8_lossy(&out.stderr)))
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs pymodbus (.ci/install-witnesses.sh)"]
async fn pymodbus_reads_the_map_and_runs_a_drive() {
    if !witness("pymodbus", has_pymodbus(), "python3 -m pip install pymodbus") {
        return;
    }
    let addr = serve_demo().await;
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/pymodbus_gateway.py");
    let mut cmd = Command::new("python3");
    cmd.arg(script).arg(addr.port().to_string());
    match run(cmd).await {
        Ok(out) => {
            assert!(out.contains("10 units read"), "{out}");
            eprint!("{out}");
        }
        Err(e) => panic!("pymodbus: {e}"),
    }
}

/// `mbpoll -m tcp -p <port> <args>`: its stdout, or the failure with its stderr.
async fn mbpoll(port: &str, args: &[&str]) -> Result<String, String> {
    let mut cmd = Command::new("mbpoll");
    cmd.args(["-m", "tcp", "-p", port]).args(args);
    run(cmd).await
}

/// `mbpoll -m tcp -p <port> <args>` that succeeds: its stdout.
async fn mbpoll_ok(port: &str, args: &[&str]) -> String {
    mbpoll(port, args).await.unwrap_or_else(|e| panic!("mbpoll {args:?}: {e}"))
}

/// mbpoll's lines `[N]: \tVALUE` (N counts from 1).
fn mbpoll_values(out: &str) -> Vec<(u32, i64)> {
    out.lines()
        .filter_map(|l| {
            let (k, v) = l.trim().split_once("]:")?;
            Some((k.trim_start_matches('[').parse().ok()?, v.split_whitespace().next()?.parse().ok()?))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs mbpoll (.ci/install-witnesses.sh)"]
async fn mbpoll_reads_input_registers() {
    if !witness("mbpoll", has_mbpoll(), "apt-get install mbpoll") {
        return;
    }
    let addr = serve_demo().await;
    let port = addr.port().to_string();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    for unit in 1..=10u16 {
        loop {
            let unit_text = unit.to_string();
            let out =
                mbpoll_ok(&port, &["-a", &unit_text, "-t", "3", "-r", "1", "-c", "10", "-1", "127.0.0.1"])
                    .await;
            let values = mbpoll_values(&out);
            assert_eq!(values.iter().map(|v| v.0).collect::<Vec<_>>(), (1..=10).collect::<Vec<_>>(), "{out}");
            let family = if unit <= 3 {
                1
            } else if unit <= 6 {
                2
            } else if unit <= 8 {
                3
            } else {
                4
            };
            assert_eq!(values[8].1, family, "unit {unit} family: {out}");
            if values[0].1 & 0x08 != 0 {
                assert_eq!(values[5].1, 1, "unit {unit} link status: {out}");
                break;
            }
            assert!(tokio::time::Instant::now() < deadline, "unit {unit} never online: {out}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
    // An unknown unit: mbpoll reports the gateway's exception.
    let out = mbpoll(&port, &["-a", "42", "-t", "3", "-r", "1", "-c", "1", "-1", "127.0.0.1"])
        .await
        .unwrap_or_else(|e| e);
    assert!(out.to_lowercase().contains("target device failed to respond"), "{out}");

    // Writes: fan-1's (unit 3) setpoint to 35.00 Hz (FC 06, answered when the drive confirmed),
    // read back from holding register 1; then command word and setpoint together (FC 16).
    let out = mbpoll_ok(&port, &["-a", "3", "-t", "4", "-r", "2", "127.0.0.1", "3500"]).await;
    assert!(out.contains("Written 1 references"), "{out}");
    let out = mbpoll_ok(&port, &["-a", "3", "-t", "4", "-r", "2", "-c", "1", "-1", "127.0.0.1"]).await;
    assert_eq!(mbpoll_values(&out), vec![(2, 3500)], "{out}");
    let out = mbpoll_ok(&port, &["-a", "3", "-t", "4", "-r", "1", "127.0.0.1", "1", "3000"]).await;
    assert!(out.contains("Written 2 references"), "{out}");
    let out = mbpoll_ok(&port, &["-a", "3", "-t", "4", "-r", "1", "-c", "2", "-1", "127.0.0.1"]).await;
    assert_eq!(mbpoll_values(&out), vec![(1, 1), (2, 3000)], "{out}");
    // pump-3 (unit 6) is locked: mbpoll shows the exception.
    let out = mbpoll(&port, &["-a", "6", "-t", "4", "-r", "1", "127.0.0.1", "1"]).await.unwrap_or_else(|e| e);
    assert!(out.to_lowercase().contains("illegal function"), "{out}");
}
