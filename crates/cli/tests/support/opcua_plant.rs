//! The plant the OPC UA interop tests run their clients against: `drivebus serve` on the demo's
//! buses, plus a drive on a `drivebus simulate` process (for the client to trip and silence
//! through its control interface) and one on a serial port that does not exist, with a write
//! token for user `demo` and the client's certificate in `[opcua] trusted_clients`.

#![allow(dead_code)]

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

#[path = "lines.rs"]
pub mod lines;
use lines::{serve_command, wait_for_lines, Killed};

/// The write token of user `demo`.
pub const TOKEN: &str = "opcua-test-token-0123456789";
/// Every drive of the plant, as the clients expect them under Objects/Drives.
pub const DRIVES: &str =
    "conveyor-1,conveyor-2,fan-1,pump-1,pump-2,pump-3,ahu-1,ahu-2,mixer-1,mixer-2,press-1,ghost-1";
/// The drive on a port that does not exist.
pub const OFFLINE: &str = "ghost-1";
/// The drive on the simulator (address 1 there).
pub const SIMULATED: &str = "press-1";

/// A running `drivebus serve --config` with OPC UA; killed on drop.
pub struct Serve {
    /// The gateway's HTTP address.
    pub http: SocketAddr,
    /// The OPC UA endpoint URL the gateway printed.
    pub url: String,
    _child: Killed,
}

impl Serve {
    /// Starts `drivebus serve --config file` with HTTP and Modbus TCP on free loopback ports,
    /// OPC UA on `opcua` and the further flags `extra`; returns once it has printed its
    /// dashboard and OPC UA lines.
    pub fn start(file: &Path, opcua: &str, extra: &[&str]) -> Serve {
        let mut child = serve_command(opcua).arg("--config").arg(file).args(extra).spawn().unwrap();
        let at = wait_for_lines(&mut child, "drivebus serve", &["dashboard", "OPC UA"]);
        let child = Killed(child);
        let http = at[0].trim_start_matches("http://").trim_end_matches('/').parse().unwrap();
        let url = at[1].split_whitespace().next().unwrap().to_string();
        Serve { http, url, _child: child }
    }
}

/// The running plant; its processes are killed on drop.
pub struct Plant {
    /// The gateway's HTTP address.
    pub http: SocketAddr,
    /// `opc.tcp://127.0.0.1:<port>/`.
    pub url: String,
    /// `http://<simulator's control address>`.
    pub control: String,
    /// The gateway's certificate (DER), made on its first start.
    pub server_cert: PathBuf,
    _serve: Serve,
    _sim: Killed,
}

impl Plant {
    /// Starts the simulator and `serve` with their files in `dir`, trusting the client
    /// certificate `client_der`.
    pub fn start(dir: &Path, client_der: &Path) -> Plant {
        Plant::start_with(dir, client_der, "")
    }

    /// [`Plant::start`] with `opcua`, more lines of the `[opcua]` table (e.g.
    /// `insecure_writes = true\n`).
    pub fn start_with(dir: &Path, client_der: &Path, opcua: &str) -> Plant {
        let mut sim = Command::new(env!("CARGO_BIN_EXE_drivebus"))
            .args(["simulate", "--drive", "generic@1:modbus-rtu", "--baud", "19200", "--serial", "8N1"])
            .args(["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let at = wait_for_lines(&mut sim, "drivebus simulate", &["listening on tcp", "control http://"]);
        let sim = Killed(sim);
        let control = format!("http://{}", at[1].trim_end_matches("/drives"));

        // The demo's buses and drives, with the store (and so the server's pki) in `dir`.
        let demo =
            std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../gateway/src/demo.toml"))
                .unwrap();
        let store = format!("path = \"{}\"", dir.join("store.db").display());
        let demo = if demo.contains("path = \"drivebus-demo.db\"") {
            demo.replace("path = \"drivebus-demo.db\"", &store)
        } else {
            format!("{demo}\n[store]\n{store}\n")
        };
        let config = format!(
            "{demo}\n[[token]]\nname = \"demo\"\ntoken = \"{TOKEN}\"\nrole = \"write\"\n\
             [opcua]\ntrusted_clients = [\"{}\"]\n{opcua}\
             [[bus]]\nname = \"line-a\"\nport = \"tcp://{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
             [[bus.drive]]\nname = \"{SIMULATED}\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n\
             [[bus]]\nname = \"line-b\"\nport = \"{}\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\nserial = \"8N1\"\n\
             [[bus.drive]]\nname = \"{OFFLINE}\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 200\n",
            client_der.display(),
            at[0],
            dir.join("ttyUSB-unplugged").display()
        );
        let file = dir.join("plant.toml");
        std::fs::write(&file, config).unwrap();
        let serve = Serve::start(&file, "127.0.0.1:0", &[]);
        let (http, url) = (serve.http, serve.url.clone());
        assert!(url.starts_with("opc.tcp://127.0.0.1:"), "{url}");
        // The certificate the server made for itself on first start, in pki beside the store.
        let server_cert = dir.join("pki/own/cert.der");
        assert!(server_cert.exists(), "no server certificate at {}", server_cert.display());
        Plant { http, url, control, server_cert, _serve: serve, _sim: sim }
    }
}
