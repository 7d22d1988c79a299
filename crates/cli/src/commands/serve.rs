//! `drivebus serve`: the gateway service over every configured bus (or the embedded demo).

use drivebus_gateway::text::count;
use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{anyhow, Context, Result};
use clap::Args;
use drivebus_gateway::config::{MqttConfig, Role, SparkplugConfig, Token};
use drivebus_gateway::{Gateway, GatewayConfig};

use crate::commands::target::Failure;

/// Arguments of `drivebus serve`.
#[derive(Args, Clone, Debug)]
pub struct ServeArgs {
    /// The gateway's TOML configuration (see docs/gateway.md).
    #[arg(long, value_name = "FILE", required_unless_present = "demo", conflicts_with = "demo")]
    pub config: Option<PathBuf>,
    /// Run the embedded demo: a virtual bus per family with simulated drives, nothing attached.
    #[arg(long)]
    pub demo: bool,
    /// Listen for HTTP on HOST:PORT (default 127.0.0.1:8080).
    #[arg(long, value_name = "HOST:PORT")]
    pub http: Option<SocketAddr>,
    /// Listen for Modbus TCP on HOST:PORT (default 127.0.0.1:5020).
    #[arg(long, value_name = "HOST:PORT")]
    pub modbus: Option<SocketAddr>,
    /// Serve OPC UA on HOST:PORT (default 127.0.0.1:4840; docs/opcua.md).
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "no_opcua")]
    pub opcua: Option<SocketAddr>,
    /// No OPC UA server.
    #[arg(long)]
    pub no_opcua: bool,
    /// Publish to an MQTT broker, mqtt://HOST:PORT, or mqtts://HOST[:PORT] over TLS (the
    /// configuration's [mqtt] ca_file and client certificate apply).
    #[arg(long, value_name = "URL")]
    pub mqtt: Option<String>,
    /// Run a Sparkplug B edge node on this broker, mqtt://HOST:PORT or mqtts://HOST[:PORT]
    /// (TLS) (docs/sparkplug.md); the configuration's other [sparkplug] settings stay.
    #[arg(long, value_name = "URL")]
    pub sparkplug: Option<String>,
    /// The Sparkplug primary host id: publish only while its STATE says online.
    #[arg(long, value_name = "HOST_ID")]
    pub sparkplug_primary: Option<String>,
    /// The event store (SQLite file); overrides the configuration's.
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Keep no events or trends.
    #[arg(long, conflicts_with = "db")]
    pub no_store: bool,
    /// A transparent Modbus bridge: Modbus TCP on HOST:PORT straight through to bus BUS (unit id
    /// = the drive's address on the bus), as [[bridge]] does; repeat for more.
    #[arg(long, value_name = "BUS=HOST:PORT")]
    pub bridge: Vec<String>,
    /// Serve the unified register map as a Modbus RTU slave on DEVICE (19200 8E1, read-only;
    /// [[modbus_rtu]] sets the baud, format and writes).
    #[arg(long, value_name = "DEVICE")]
    pub modbus_rtu: Vec<String>,
    /// The gateway's name, instead of the configuration's (`demo` with --demo): the MQTT topic
    /// level and client id, so that two gateways on one broker stay apart.
    #[arg(long, value_name = "NAME")]
    pub name: Option<String>,
    /// Start as a standby (`[standby] role = "standby"`): listen to another gateway on the same
    /// lines, take a line over when it falls silent for `[standby] silence_ms` (500 ms).
    #[arg(long)]
    pub standby: bool,
    /// How log lines on stderr are written: `text` (one sentence each) or `json` (one object
    /// each, for log shippers reading the journal).
    #[arg(long, value_name = "FORMAT", default_value = "text")]
    pub log_format: drivebus_gateway::log::Format,
}

fn demo_token() -> String {
    let mut bytes = [0u8; 16];
    if let Ok(mut f) = std::fs::File::open("/dev/urandom") {
        use std::io::Read;
        let _ = f.read_exact(&mut bytes);
    }
    if bytes == [0; 16] {
        // No /dev/urandom: derive one from the clock and the process (still unique per run).
        let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        let seed = t.as_nanos() ^ (u128::from(std::process::id()) << 64);
        bytes = seed.to_le_bytes();
    }
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Reads a configuration file as `serve` does; errors name the file, the line and the field.
pub fn read_config(path: &std::path::Path) -> Result<GatewayConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the configuration {}", path.display()))?;
    Ok(GatewayConfig::from_toml(&path.display().to_string(), &text)?)
}

/// The configuration `serve` runs: the file (or the demo) with the command line's overrides and
/// the demo's token. Read again, the same way, on each reload.
fn load(args: &ServeArgs, demo_token: Option<&str>) -> Result<GatewayConfig> {
    let mut config = match &args.config {
        Some(path) => read_config(path)?,
        None => GatewayConfig::demo(),
    };
    if let Some(name) = &args.name {
        if !drivebus_gateway::config::valid_name(name) {
            return Err(anyhow!(
                "--name {name:?}: use letters, digits, '-' and '_' (it is an MQTT topic level)"
            ));
        }
        config.name = name.clone();
    }
    if let Some(a) = args.http {
        config.http.listen = a;
    }
    if let Some(a) = args.modbus {
        config.modbus.listen = a;
    }
    if args.no_opcua {
        config.opcua = None;
    } else if let Some(a) = args.opcua {
        let http = config.http.anonymous_read;
        config.opcua.get_or_insert(drivebus_gateway::config::OpcUaConfig::new(a, http)).listen = a;
    }
    if args.demo {
        // The demo's writes over the None endpoint, where nobody else is on the path.
        if let Some(o) = config.opcua.as_mut() {
            o.insecure_writes = o.listen.ip().is_loopback();
        }
    }
    if let Some(url) = &args.mqtt {
        drivebus_gateway::mqtt::parse_url(url).map_err(|e| anyhow!("--mqtt {e}"))?;
        let mut m = config.mqtt.clone().unwrap_or(MqttConfig {
            url: url.clone(),
            topic_prefix: None,
            discovery: false,
            allow_commands: Vec::new(),
            client_id: None,
            credentials: None,
            tls: Default::default(),
        });
        m.url = url.clone();
        config.mqtt = Some(m);
    }
    for b in &args.bridge {
        let b = drivebus_gateway::bridge::parse_arg(b).map_err(|e| anyhow!(e))?;
        drivebus_gateway::bridge::check(&b, &config.buses).map_err(|e| anyhow!(e))?;
        config.bridges.push(b);
    }
    for port in &args.modbus_rtu {
        config.modbus_rtu.push(drivebus_gateway::modbus_rtu::ModbusRtuConfig::new(port));
    }
    sparkplug_overrides(args, &mut config)?;
    if args.standby {
        for b in &mut config.buses {
            let silence = b.role.map_or(drivebus_link::role::RoleConfig::DEFAULT_SILENCE, |r| r.silence);
            if let Some(why) = drivebus_gateway::config::no_standby(b) {
                return Err(anyhow!("--standby: {why}"));
            }
            b.role = Some(drivebus_link::role::RoleConfig { standby: true, silence });
            if let Some(poll) = b.drives.iter().map(|d| d.poll).min().filter(|p| *p > silence) {
                return Err(anyhow!(
                    "--standby: bus {}'s poll_ms {} is longer than the silence of {} ms that hands a line over: the line falls silent between polls; set [standby] silence_ms at least that",
                    b.name,
                    poll.as_millis(),
                    silence.as_millis()
                ));
            }
        }
    }
    if args.no_store {
        config.store = None;
    } else if let Some(db) = &args.db {
        config.store = Some(db.clone());
    }
    if let Some(t) = demo_token {
        config.tokens.push(Token { name: "demo".into(), secret: t.to_string(), role: Role::Write });
    }
    Ok(config)
}

/// `--sparkplug` and `--sparkplug-primary` over the configuration's `[sparkplug]`; the demo
/// accepts DCMD commands.
fn sparkplug_overrides(args: &ServeArgs, config: &mut GatewayConfig) -> Result<()> {
    if let Some(url) = &args.sparkplug {
        drivebus_gateway::mqtt::parse_url(url).map_err(|e| anyhow!("--sparkplug {e}"))?;
        let mut sp = config.sparkplug.clone().unwrap_or_else(|| SparkplugConfig::new(url));
        sp.urls = vec![url.clone()];
        sp.commands |= args.demo;
        config.sparkplug = Some(sp);
    }
    if let Some(host) = &args.sparkplug_primary {
        drivebus_gateway::sparkplug::check_id(host).map_err(|e| anyhow!("--sparkplug-primary {e}"))?;
        let sp = config.sparkplug.as_mut().ok_or_else(|| {
            anyhow!(
                "--sparkplug-primary needs a broker: give --sparkplug mqtt[s]://HOST:PORT or [sparkplug] urls"
            )
        })?;
        sp.primary_host = Some(host.clone());
    }
    Ok(())
}

/// Runs `drivebus serve`.
pub fn run(args: &ServeArgs) -> Result<u8> {
    drivebus_gateway::log::set_format(args.log_format);
    let token = args.demo.then(demo_token);
    let config = load(args, token.as_deref())?;
    if config.buses.is_empty() {
        eprintln!(
            "drivebus serve: warning: the configuration has no [[bus]]: nothing will be polled \
             (docs/gateway.md shows a bus with its drives)"
        );
    }
    // A configuration that locks everyone out of the HTTP API is legal (Modbus TCP and MQTT
    // still work) but almost never meant: say so at start, not with a 401 later.
    if !config.http.anonymous_read && config.tokens.is_empty() {
        eprintln!(
            "drivebus serve: warning: no [[token]] and anonymous_read = false: every HTTP request \
             (dashboard included) will be refused with 401; add a [[token]] or set \
             [http] anonymous_read = true (docs/gateway.md)"
        );
    } else if !config.tokens.iter().any(|t| t.role == Role::Write) {
        eprintln!(
            "drivebus serve: note: no [[token]] with role = \"write\": HTTP commands and \
             parameter writes will be refused with 403"
        );
    }
    let store = match &config.store {
        Some(path) => {
            let state = drivebus_gateway::config::state_dir::state_dir().ok();
            if args.db.is_none() && path.parent().is_some() && path.parent() == state.as_deref() {
                // The default store (the demo's too) is in the state folder, made here on first
                // run; a folder the user named is theirs to make.
                if let Some(dir) = path.parent() {
                    std::fs::create_dir_all(dir)
                        .with_context(|| format!("cannot make the state folder {}", dir.display()))?;
                }
            }
            let store = drivebus_store::Store::open_with_limits(path, config.store_limits);
            Some(store.map_err(|e| Failure { code: 2, message: e.to_string() })?)
        }
        None => None,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async move {
        let db = config.store.clone();
        let gw = Gateway::start(config, store).map_err(|e| Failure { code: 3, message: e })?;
        // Events (trips, drives and buses going offline and back, commands) one line each.
        gw.log_events(true);
        // SIGHUP reads the file again, with the same overrides (the demo has no file).
        let loader: Option<drivebus_gateway::server::Loader> = args.config.is_some().then(|| {
            let args = args.clone();
            let token = token.clone();
            Box::new(move || load(&args, token.as_deref()).map_err(|e| format!("{e:#}")))
                as drivebus_gateway::server::Loader
        });
        drivebus_gateway::server::run(gw.clone(), loader, |bound| {
            println!(
                "drivebus serve: {}, {}",
                count(gw.buses().len(), "bus", "buses"),
                count(gw.drives().len(), "drive", "drives")
            );
            let scheme = if gw.config().http.tls.is_some() { "https" } else { "http" };
            println!("  dashboard   {scheme}://{}/", bound.http);
            println!("  HTTP API    {scheme}://{}/api/drives", bound.http);
            println!("  Modbus TCP  {} (unit id = drive, docs/register-map.md)", bound.modbus);
            if let (Some(a), Some(o)) = (bound.opcua, &gw.config().opcua) {
                let url =
                    drivebus_gateway::opcua::endpoint_url(o, a).unwrap_or_else(|_| format!("opc.tcp://{a}"));
                println!("  OPC UA      {url} (namespace urn:drivebus, docs/opcua.md)");
                if o.insecure_writes {
                    let why = if args.demo { "the demo, on loopback" } else { "[opcua] insecure_writes" };
                    println!("  OPC UA      writes and calls also over the unsigned None endpoint ({why})");
                }
                if let Ok(pki) = drivebus_gateway::opcua::pki_dir(&gw.config(), o) {
                    println!("  OPC UA key  {}", pki.join("private/private.pem").display());
                }
            }
            for (bus, at) in &bound.bridges {
                println!("  bridge      {at} -> bus {bus} (Modbus TCP straight through, docs/gateway.md)");
            }
            for m in &gw.config().modbus_rtu {
                println!("  Modbus RTU  slave on {} at {} {} (unit id = drive)", m.port, m.baud, m.format);
            }
            if let Some(m) = &gw.config().mqtt {
                let prefix = m
                    .topic_prefix
                    .clone()
                    .unwrap_or_else(|| drivebus_gateway::mqtt::default_prefix(&gw.config().name));
                println!("  MQTT        {} (topics under {prefix}/, docs/mqtt.md)", m.url);
            }
            if let Some(sp) = &gw.config().sparkplug {
                let edge = sp.edge_node_id.clone().unwrap_or_else(|| gw.config().name.clone());
                println!(
                    "  Sparkplug B {} (spBv1.0/{}/+/{edge}, docs/sparkplug.md)",
                    sp.urls.join(", "),
                    sp.group_id
                );
            }
            match &db {
                Some(p) => println!("  event store {}", p.display()),
                None => println!("  event store off"),
            }
            if let Some(t) = &token {
                println!("  demo write token: {t}");
                println!(
                    "  e.g. curl -X POST -H 'Authorization: Bearer {t}' http://{}/api/drives/pump-1/run",
                    bound.http
                );
            }
            use std::io::Write;
            let _ = std::io::stdout().flush();
        })
        .await
        .map_err(|e| Failure { code: 2, message: e })?;
        Ok::<u8, Failure>(0)
    })
    .map_err(Into::into)
}
