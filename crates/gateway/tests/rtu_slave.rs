//! The Modbus RTU slave's port is a bus's port like the others: missing at start, the gateway
//! runs and `/readyz`'s facts name it; when it appears (a pseudo-terminal) it is served; lost,
//! it is named again and opened again when it is back. Its writes follow `[modbus] read_only` as
//! configured when they come, so a reload applies. Real time with generous deadlines (the port
//! is a real pty); the retry schedule itself is tested on the paused clock in modbus_rtu.rs.

mod support;

use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use drivebus_gateway::bridge::bus_frame;
use drivebus_gateway::{Gateway, GatewayConfig};
use support::wait_for;

const PATIENCE: Duration = Duration::from_secs(30);

/// A virtual bus with a generic drive `pump-1` (unit id 1) and a writing RTU slave on `port`;
/// `modbus` is extra `[modbus]` settings.
fn config(port: &Path, modbus: &str) -> GatewayConfig {
    let text = format!(
        "name = \"rtu-slave\"\n[modbus]\nlisten = \"127.0.0.1:0\"\n{modbus}\n[store]\ndisabled = true\n\
         [[bus]]\nname = \"line-1\"\nport = \"virtual\"\nprotocol = \"modbus-rtu\"\nbaud = 19200\n\
         [[bus.drive]]\nname = \"pump-1\"\nfamily = \"generic\"\naddress = 1\npoll_ms = 100\n\
         [[modbus_rtu]]\nport = {:?}\nbaud = 19200\nserial = \"8N1\"\nwrite = true\n",
        port.display().to_string()
    );
    GatewayConfig::from_toml("rtu-slave.toml", &text).unwrap()
}

/// A pseudo-terminal in raw mode whose slave side is at `link` (a symlink): the master side
/// for the test to talk on, what it reads handed over a channel.
struct Pty {
    master: std::fs::File,
    heard: mpsc::Receiver<u8>,
    stop: Arc<AtomicBool>,
    _slave: OwnedFd,
    link: PathBuf,
}

impl Pty {
    fn at(link: &Path) -> Pty {
        use nix::sys::termios;
        let p = nix::pty::openpty(None, None).unwrap();
        let mut t = termios::tcgetattr(p.slave.as_fd()).unwrap();
        termios::cfmakeraw(&mut t);
        termios::tcsetattr(p.slave.as_fd(), termios::SetArg::TCSANOW, &t).unwrap();
        std::os::unix::fs::symlink(nix::unistd::ttyname(p.slave.as_fd()).unwrap(), link).unwrap();
        let master = std::fs::File::from(p.master);
        let mut reader = master.try_clone().unwrap();
        // Non-blocking, so that the reader sees the test drop the pty and closes its copy of the
        // master too: only then does the gateway's side see the port gone.
        use nix::fcntl::{fcntl, FcntlArg, OFlag};
        fcntl(std::os::fd::AsRawFd::as_raw_fd(&reader), FcntlArg::F_SETFL(OFlag::O_NONBLOCK)).unwrap();
        let (tx, heard) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            loop {
                match reader.read(&mut buf) {
                    Ok(n @ 1..) => {
                        if buf[..n].iter().any(|b| tx.send(*b).is_err()) {
                            return;
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        if stopped.load(Ordering::Relaxed) {
                            return;
                        }
                        std::thread::sleep(Duration::from_millis(2));
                    }
                    _ => return,
                }
            }
        });
        Pty { master, heard, stop, _slave: p.slave, link: link.to_path_buf() }
    }

    /// Sends `pdu` to `unit` as an RTU frame; the answer's PDU (of `len` bytes, CRC checked).
    fn ask(&mut self, unit: u8, pdu: &[u8], len: usize) -> Vec<u8> {
        self.master.write_all(&bus_frame(false, unit, pdu)).unwrap();
        let mut frame = Vec::new();
        while frame.len() < len + 3 {
            // On this worker alone (multi-thread runtime): the gateway's tasks run meanwhile.
            let b = tokio::task::block_in_place(|| self.heard.recv_timeout(PATIENCE));
            frame.push(b.unwrap_or_else(|_| panic!("no whole answer to {pdu:02X?}: {frame:02X?}")));
        }
        assert_eq!(frame[0], unit, "{frame:02X?}");
        let pdu = frame[1..=len].to_vec();
        assert_eq!(bus_frame(false, unit, &pdu), frame, "a bad CRC");
        pdu
    }

    /// The port goes away: both sides closed (the reader's copy too), the link removed.
    fn remove(self) {}
}

impl Drop for Pty {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = std::fs::remove_file(&self.link);
    }
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("drivebus-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Why the gateway is not ready because of the slave on `port`, if it is not.
fn slave_down(gw: &Gateway, port: &Path) -> Option<String> {
    let name = format!("Modbus RTU slave on {} is down", port.display());
    gw.not_ready().into_iter().find(|w| w.starts_with(&name))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_slave_port_is_named_and_served_once_it_appears_and_again_after_a_loss() {
    let dir = temp_dir("rtu-port");
    let port = dir.join("ttyRTU");
    let cfg = config(&port, "");
    let gw: Arc<Gateway> = Gateway::start(cfg.clone(), None).unwrap();
    tokio::spawn(drivebus_gateway::modbus_rtu::run(gw.clone(), cfg.modbus_rtu[0].clone()));

    // No port: the gateway runs, polls, and says the slave is down and why.
    wait_for("the slave named down", PATIENCE, || slave_down(&gw, &port).is_some()).await;
    let why = slave_down(&gw, &port).unwrap();
    assert!(why.contains(&port.display().to_string()), "{why}");
    wait_for("pump-1 polled meanwhile", PATIENCE, || {
        gw.drive_view(&gw.drive("pump-1").unwrap()).online == Some(true)
    })
    .await;
    let metrics = drivebus_gateway::metrics::render(&gw).unwrap();
    let series = format!("drivebus_modbus_rtu_up{{port=\"{}\"}} 0", port.display());
    assert!(metrics.contains(&series), "{metrics}");

    // The port appears: it is opened on the next try and serves the map (input register 9:
    // the drive's address).
    let mut pty = Pty::at(&port);
    wait_for("the slave up", PATIENCE, || slave_down(&gw, &port).is_none()).await;
    assert_eq!(pty.ask(1, &[0x04, 0x00, 0x09, 0x00, 0x01], 4), [0x04, 2, 0, 1]);
    let metrics = drivebus_gateway::metrics::render(&gw).unwrap();
    assert!(metrics.contains(&series.replace("} 0", "} 1")), "{metrics}");

    // The port is lost: named again, and opened again when it is back.
    pty.remove();
    wait_for("the lost port named", PATIENCE, || slave_down(&gw, &port).is_some()).await;
    let mut pty = Pty::at(&port);
    wait_for("the slave up again", PATIENCE, || slave_down(&gw, &port).is_none()).await;
    assert_eq!(pty.ask(1, &[0x04, 0x00, 0x09, 0x00, 0x01], 4), [0x04, 2, 0, 1]);
    pty.remove();
    let _ = std::fs::remove_dir_all(&dir);
}

/// `[modbus] read_only` is read at each write: a reload that turns it on refuses the slave's
/// next write (exception 01) without a restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_to_read_only_refuses_the_slaves_next_write() {
    let dir = temp_dir("rtu-read-only");
    let port = dir.join("ttyRTU");
    let mut pty = Pty::at(&port);
    let cfg = config(&port, "");
    let gw = Gateway::start(cfg.clone(), None).unwrap();
    tokio::spawn(drivebus_gateway::modbus_rtu::run(gw.clone(), cfg.modbus_rtu[0].clone()));
    wait_for("pump-1 online", PATIENCE, || gw.drive_view(&gw.drive("pump-1").unwrap()).online == Some(true))
        .await;
    // Holding register 1: the setpoint, 0.01 Hz.
    let write = [0x06, 0x00, 0x01, 0x0F, 0xA0];
    assert_eq!(pty.ask(1, &write, 5), write);
    let plan = gw.reload(config(&port, "read_only = true"), "test").await.unwrap();
    assert!(plan.needs_restart.is_empty(), "{plan:?}");
    assert_eq!(pty.ask(1, &write, 2), [0x86, 0x01]);
    pty.remove();
    let _ = std::fs::remove_dir_all(&dir);
}
