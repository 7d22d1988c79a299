//! OPC UA with a second client stack nobody here wrote: node-opcua (npm, pinned in
//! tests/interop/node/package.json) against `drivebus serve` on the plant of
//! support/opcua_plant.rs. tests/interop/node/opcua_client.js does the client's side and prints
//! one line per check: browse, reads with status and timestamps (the source timestamp of a value
//! that does not change follows the polls, AgeMs its age), engineering units,
//! TranslateBrowsePaths, subscriptions (the default trigger and StatusValueTimestamp), method
//! calls and their refusals, writes and their type checks, event items on the Server object and
//! the Drives folder (events, never a data change), and a Basic256Sha256 SignAndEncrypt session
//! with a client certificate made here and trusted through `[opcua] trusted_clients`.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "support/opcua_plant.rs"]
mod plant;
#[path = "../../../tests/interop/witness.rs"]
mod witness;
use witness::witness;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/node/opcua_client.js")
}

/// Node with tests/interop/node as its working directory, where node-opcua is installed.
fn node() -> Command {
    let mut node = Command::new("node");
    node.current_dir(script().parent().unwrap());
    node
}

/// Whether Node runs and finds node-opcua where .ci/install-witnesses.sh installs it.
fn node_opcua_here() -> bool {
    node().args(["-e", "require('node-opcua')"]).output().is_ok_and(|o| o.status.success())
}

fn run_script(args: &[&std::ffi::OsStr]) -> std::process::Output {
    node().arg(script()).args(args).output().unwrap()
}

#[test]
#[ignore = "needs node-opcua (.ci/install-witnesses.sh)"]
fn node_opcua_browses_reads_subscribes_commands_and_is_refused_where_it_should_be() {
    if !witness("node-opcua", node_opcua_here(), "Node.js, then npm ci in tests/interop/node") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("drivebus-opcua-node-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();

    // The client's certificate, made for this run only and trusted by the gateway's configuration.
    let client = dir.join("client");
    let out = run_script(&["mkcert".as_ref(), client.as_os_str()]);
    assert!(out.status.success(), "mkcert: {}", String::from_utf8_lossy(&out.stderr));

    let plant = plant::Plant::start(&dir, &client.join("client.der"));
    let out = run_script(&[
        "check".as_ref(),
        plant.url.as_ref(),
        plant::TOKEN.as_ref(),
        plant::DRIVES.as_ref(),
        plant::OFFLINE.as_ref(),
        plant::SIMULATED.as_ref(),
        plant.control.as_ref(),
        client.as_os_str(),
        plant.server_cert.as_os_str(),
    ]);
    let said = String::from_utf8_lossy(&out.stdout);
    eprintln!("{said}");
    assert!(
        out.status.success() && said.contains("ALL OK"),
        "the node-opcua client: {said}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
