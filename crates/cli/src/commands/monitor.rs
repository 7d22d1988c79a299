//! `drivebus monitor`: a live view of one or more drives on one bus: each drive's state, a
//! trend of output frequency and current, and the bus's link statistics.
//!
//! On a terminal it draws with ratatui (crossterm backend) until `q`, Esc or Ctrl-C; when
//! stdout is not a terminal, or with `--plain`, it prints one line per drive per refresh
//! (`--count N` stops after N refreshes), which is how scripts and tests use it.
//!
//! The view is a pure function of [`MonitorState`] ([`render`]), so it is tested on ratatui's
//! `TestBackend` without a terminal or a bus.

use std::collections::{HashMap, VecDeque};
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Result;
use clap::Args;
use drivebus_drive::profile::DriveStatus;
use drivebus_link::drive::{open_with, Drive};
use drivebus_link::{BusStats, Health};
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Cell, Paragraph, Row, Sparkline, Table};
use ratatui::Frame;
use serde_json::json;

use crate::commands::drive::{classify, resolve_for, runtime};
use crate::commands::target::{link_failure, usage, Target};

/// Samples kept per drive for the trend.
pub const HISTORY: usize = 240;

/// Arguments of `drivebus monitor` (with `crate::options`' --port, --drive, one or more --address,
/// --protocol, --baud, --serial, --timeout, --retries, --json).
#[derive(Args, Debug)]
pub struct MonitorArgs {
    /// Time between refreshes, in milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    pub interval: u64,
    /// Print one line per drive per refresh instead of the live view (the default when
    /// stdout is not a terminal).
    #[arg(long)]
    pub plain: bool,
    /// Stop after N refreshes (default: run until q, Esc or Ctrl-C, or until interrupted).
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
}

/// What the monitor knows about one drive.
#[derive(Clone, Debug, Default)]
pub struct DriveView {
    /// The drive's address.
    pub address: u8,
    /// The last status read, if any.
    pub status: Option<DriveStatus>,
    /// The last refresh's error, if it failed.
    pub error: Option<String>,
    /// Monitor time of the last good read, seconds.
    pub last_ok_s: Option<f64>,
    /// The bus owner's view of the drive's link.
    pub online: bool,
    /// Output frequency history, Hz (oldest first).
    pub hz: VecDeque<f64>,
    /// Current history, A (oldest first).
    pub amps: VecDeque<f64>,
}

impl DriveView {
    /// A drive not read yet.
    pub fn new(address: u8) -> Self {
        DriveView { address, online: true, ..DriveView::default() }
    }

    /// Records a refresh at monitor time `now_s`.
    pub fn record(&mut self, now_s: f64, result: Result<DriveStatus, String>, health: Option<&Health>) {
        match result {
            Ok(s) => {
                push(&mut self.hz, s.output_hz.unwrap_or(0.0));
                push(&mut self.amps, s.current_a.unwrap_or(0.0));
                self.status = Some(s);
                self.error = None;
                self.last_ok_s = Some(now_s);
            }
            Err(e) => self.error = Some(e),
        }
        self.online = health.map_or(self.error.is_none(), |h| h.online);
    }

    /// Seconds since the last good read at monitor time `now_s`.
    pub fn age(&self, now_s: f64) -> Option<f64> {
        self.last_ok_s.map(|t| (now_s - t).max(0.0))
    }

    /// `running`, `stopped`, `fault` or `no data`.
    pub fn state(&self) -> &'static str {
        match &self.status {
            None => "no data",
            Some(s) if s.fault.is_some() => "fault",
            Some(s) if s.running => "running",
            Some(_) => "stopped",
        }
    }
}

fn push(v: &mut VecDeque<f64>, x: f64) {
    if v.len() == HISTORY {
        v.pop_front();
    }
    v.push_back(x);
}

/// Everything the view shows.
#[derive(Clone, Debug, Default)]
pub struct MonitorState {
    /// What is monitored, for the title (`generic modbus-rtu on tcp://...`).
    pub title: String,
    /// Refresh interval, milliseconds.
    pub interval_ms: u64,
    /// Monitor time of the last refresh, seconds.
    pub now_s: f64,
    /// Refreshes done.
    pub refreshes: u64,
    /// The drives, in the order given.
    pub drives: Vec<DriveView>,
    /// The bus's counts.
    pub stats: BusStats,
}

fn hz(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.2}"))
}

/// One line per drive, as `--plain` prints it.
pub fn plain_line(state: &MonitorState, d: &DriveView) -> String {
    let s = d.status.as_ref();
    let fault = match s.and_then(|s| s.fault.as_ref()) {
        Some(f) => format!("{} {}", f.code, f.text),
        None => "none".into(),
    };
    let mut line = format!(
        "t={:.1}s drive={} state={} dir={} output_hz={} setpoint_hz={} current_a={} fault=\"{}\" online={} age={}",
        state.now_s,
        d.address,
        d.state(),
        s.and_then(|s| s.direction.as_deref()).unwrap_or("-"),
        hz(s.and_then(|s| s.output_hz)),
        hz(s.and_then(|s| s.setpoint_hz)),
        s.and_then(|s| s.current_a).map_or("-".into(), |a| format!("{a:.1}")),
        fault,
        if d.online { "yes" } else { "no" },
        d.age(state.now_s).map_or("-".into(), |a| format!("{a:.1}s")),
    );
    if let Some(e) = &d.error {
        line.push_str(&format!(" error=\"{e}\""));
    }
    line
}

/// One JSON object per drive, as `--plain --json` prints it.
pub fn plain_json(state: &MonitorState, d: &DriveView) -> serde_json::Value {
    let s = d.status.as_ref();
    // Times to the millisecond: the monitor's own clock, no finer.
    let ms = |s: f64| drivebus_drive::profile::round_to(s, 3);
    json!({
        "t": ms(state.now_s),
        "address": d.address,
        "state": d.state(),
        "running": s.map(|s| s.running),
        "direction": s.and_then(|s| s.direction.clone()),
        "output_hz": s.and_then(|s| s.output_hz),
        "setpoint_hz": s.and_then(|s| s.setpoint_hz),
        "current_a": s.and_then(|s| s.current_a),
        "fault": s.and_then(|s| s.fault.as_ref()).map(|f| json!({"code": f.code, "text": f.text})),
        "online": d.online,
        "age_s": d.age(state.now_s).map(ms),
        "error": d.error,
    })
}

/// Draws the whole view into `area` of `frame`.
pub fn render(frame: &mut Frame, state: &MonitorState) {
    let area = frame.area();
    let fault_w = fault_width(area.width);
    let rows: u16 = state.drives.iter().map(|d| wrap(&fault_text(d), fault_w).len() as u16).sum();
    let table_h = rows + 3;
    let [head, table, trends, bus, foot] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Length(table_h),
        Constraint::Min(4),
        Constraint::Length(5),
        Constraint::Length(1),
    ])
    .areas(area);
    frame.render_widget(
        Paragraph::new(Line::from(vec![
            Span::styled("drivebus monitor ", Style::new().add_modifier(Modifier::BOLD)),
            Span::raw(format!("· {} · every {} ms", state.title, state.interval_ms)),
        ])),
        head,
    );
    render_table(frame, table, state);
    render_trends(frame, trends, state);
    render_bus(frame, bus, state);
    frame.render_widget(
        Paragraph::new(format!("q quit · refresh {} · t = {:.1} s", state.refreshes, state.now_s))
            .style(Style::new().fg(Color::DarkGray)),
        foot,
    );
}

/// The table's fixed columns (drive, state, dir, out Hz, set Hz, current A, link, age); the
/// fault column takes the rest of the width, its text wrapped onto more lines where needed.
const FIXED_COLUMNS: [u16; 8] = [5, 7, 7, 6, 6, 5, 7, 6];

/// The fault column's width in a table `width` columns wide (borders and spacing taken off).
fn fault_width(width: u16) -> u16 {
    let fixed: u16 = FIXED_COLUMNS.iter().sum::<u16>() + FIXED_COLUMNS.len() as u16 + 2;
    width.saturating_sub(fixed).max(8)
}

/// What the fault column says: the fault in force, else the last error, else "-".
fn fault_text(d: &DriveView) -> String {
    match (d.status.as_ref().and_then(|s| s.fault.as_ref()), &d.error) {
        (Some(f), _) => format!("{} {}", f.code, f.text),
        (None, Some(e)) => e.clone(),
        (None, None) => "-".into(),
    }
}

/// `text` cut into lines of at most `width` characters, at spaces where it can be.
fn wrap(text: &str, width: u16) -> Vec<String> {
    let width = usize::from(width.max(1));
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split(' ') {
        let mut word = word.to_string();
        loop {
            let len = line.chars().count();
            let sep = usize::from(len > 0);
            if len + sep + word.chars().count() <= width {
                if sep == 1 {
                    line.push(' ');
                }
                line.push_str(&word);
                break;
            }
            if len > 0 {
                lines.push(std::mem::take(&mut line));
                continue;
            }
            // A word longer than the line: cut it.
            let head: String = word.chars().take(width).collect();
            word = word.chars().skip(width).collect();
            lines.push(head);
            if word.is_empty() {
                break;
            }
        }
    }
    if !line.is_empty() || lines.is_empty() {
        lines.push(line);
    }
    lines
}

fn render_table(frame: &mut Frame, area: Rect, state: &MonitorState) {
    let header = Row::new(["drive", "state", "dir", "out Hz", "set Hz", "cur A", "fault", "link", "age"])
        .style(Style::new().add_modifier(Modifier::BOLD));
    let fault_w = fault_width(area.width);
    let rows = state.drives.iter().map(|d| {
        let s = d.status.as_ref();
        let state_style = match d.state() {
            "running" => Style::new().fg(Color::Green),
            "fault" => Style::new().fg(Color::Red),
            _ => Style::new(),
        };
        let fault = wrap(&fault_text(d), fault_w);
        let height = fault.len() as u16;
        Row::new(vec![
            Cell::from(d.address.to_string()),
            Cell::from(d.state()).style(state_style),
            Cell::from(s.and_then(|s| s.direction.clone()).unwrap_or_else(|| "-".into())),
            Cell::from(hz(s.and_then(|s| s.output_hz))),
            Cell::from(hz(s.and_then(|s| s.setpoint_hz))),
            Cell::from(s.and_then(|s| s.current_a).map_or("-".into(), |a| format!("{a:.1}"))),
            Cell::from(fault.into_iter().map(Line::from).collect::<Vec<_>>()),
            Cell::from(if d.online { "online" } else { "OFFLINE" }).style(if d.online {
                Style::new()
            } else {
                Style::new().fg(Color::Red)
            }),
            Cell::from(d.age(state.now_s).map_or("-".into(), |a| format!("{a:.1} s"))),
        ])
        .height(height)
    });
    let [drive, st, dir, out, set, amps, link, age] = FIXED_COLUMNS.map(Constraint::Length);
    let widths = [drive, st, dir, out, set, amps, Constraint::Min(fault_w), link, age];
    frame.render_widget(
        Table::new(rows, widths).header(header).block(Block::new().borders(Borders::ALL).title(" drives ")),
        area,
    );
}

fn render_trends(frame: &mut Frame, area: Rect, state: &MonitorState) {
    let block = Block::new().borders(Borders::ALL).title(" trend: output Hz and current A ");
    let inner = block.inner(area);
    frame.render_widget(block, area);
    if state.drives.is_empty() || inner.height < 2 {
        return;
    }
    let columns = |r: Rect| {
        Layout::horizontal([Constraint::Length(22), Constraint::Fill(1), Constraint::Fill(1)]).areas(r)
    };
    // Each half named over its column.
    let [heading, inner] = Layout::vertical([Constraint::Length(1), Constraint::Fill(1)]).areas(inner);
    let [_, hz_head, amp_head] = columns(heading);
    let dim = Style::new().fg(Color::DarkGray);
    frame.render_widget(Paragraph::new("output Hz").style(dim), hz_head);
    frame.render_widget(Paragraph::new("current A").style(dim), amp_head);
    let rows = Layout::vertical(vec![Constraint::Ratio(1, state.drives.len() as u32); state.drives.len()])
        .split(inner);
    for (d, row) in state.drives.iter().zip(rows.iter()) {
        let [label, hz_area, amp_area] = columns(*row);
        let last_hz = d.hz.back().copied();
        let last_a = d.amps.back().copied();
        frame.render_widget(
            Paragraph::new(format!(
                "drive {} {} Hz {} A",
                d.address,
                last_hz.map_or("-".into(), |x| format!("{x:.1}")),
                last_a.map_or("-".into(), |x| format!("{x:.1}")),
            )),
            label,
        );
        spark(frame, hz_area, &d.hz, 100.0, Color::Cyan);
        spark(frame, amp_area, &d.amps, 10.0, Color::Yellow);
    }
}

/// A sparkline of the newest samples that fit `area`, `scale` steps per unit.
fn spark(frame: &mut Frame, area: Rect, history: &VecDeque<f64>, scale: f64, color: Color) {
    let width = area.width as usize;
    let skip = history.len().saturating_sub(width);
    let data: Vec<u64> = history.iter().skip(skip).map(|x| (x.abs() * scale).round() as u64).collect();
    let max = data.iter().copied().max().unwrap_or(0).max(1);
    frame.render_widget(Sparkline::default().data(&data).max(max).style(Style::new().fg(color)), area);
}

fn render_bus(frame: &mut Frame, area: Rect, state: &MonitorState) {
    let s = &state.stats;
    // Three short lines: each fits an 80-column terminal whole.
    let lines = vec![
        Line::from(format!(
            "transactions {}  replies {}  timeouts {}  retries {}",
            s.transactions, s.replies, s.timeouts, s.retries
        )),
        Line::from(format!("checksum errors {}  broadcasts {}", s.checksum_errors, s.broadcasts)),
        Line::from(format!(
            "utilization {:.1} % ({:.2} s on the wire in {:.1} s)  drives online {}/{}",
            s.utilization() * 100.0,
            s.wire_seconds,
            s.elapsed_seconds,
            state.drives.iter().filter(|d| d.online).count(),
            state.drives.len()
        )),
    ];
    frame.render_widget(
        Paragraph::new(lines)
            .wrap(ratatui::widgets::Wrap { trim: true })
            .block(Block::new().borders(Borders::ALL).title(" bus ")),
        area,
    );
}

/// Reads every drive once and brings `state` up to date. The reads are handed to the bus
/// together: it sends them one at a time, or on a Modbus TCP link with `--max-in-flight` up to
/// that many at once.
async fn refresh(drives: &[Drive], state: &mut MonitorState, start: std::time::Instant) {
    let reads: Vec<_> = drives
        .iter()
        .map(|d| {
            let d = d.clone();
            tokio::spawn(async move { d.status().await.map_err(|e| e.to_string()) })
        })
        .collect();
    for ((drive, view), read) in drives.iter().zip(state.drives.iter_mut()).zip(reads) {
        let r = read.await.unwrap_or_else(|e| Err(format!("the read was lost: {e}")));
        let now_s = start.elapsed().as_secs_f64();
        let health: HashMap<u8, Health> = drive.bus().health();
        view.record(now_s, r, health.get(&view.address));
    }
    state.now_s = start.elapsed().as_secs_f64();
    state.refreshes += 1;
    if let Some(d) = drives.first() {
        state.stats = d.bus().stats();
    }
}

/// Runs `drivebus monitor`.
pub fn run(args: &MonitorArgs, t: &Target) -> Result<u8> {
    let mut addresses = t.address.clone();
    addresses.dedup();
    let Some(&first) = addresses.first() else {
        return Err(usage("say which drives: --address N (repeat it for more drives)"));
    };
    if args.interval == 0 {
        return Err(usage("--interval must be at least 1 ms"));
    }
    if args.count == Some(0) {
        return Err(usage("--count must be at least 1"));
    }
    let r = resolve_for(t, first)?;
    let mut profiles = Vec::new();
    for &a in &addresses {
        profiles.push(
            drivebus_drive::profile::for_drive(r.family, r.protocol, a).map_err(|e| usage(e.to_string()))?,
        );
    }
    let plain = args.plain || !std::io::stdout().is_terminal();
    let json = t.json;
    let interval = Duration::from_millis(args.interval);
    let count = args.count;
    runtime()?.block_on(async move {
        let bus = open_with(&r.port, r.config).await.map_err(|e| classify(e, &r.label))?;
        let drives: Vec<Drive> = profiles.into_iter().map(|p| Drive::new(bus.clone(), p).polling()).collect();
        let mut state = MonitorState {
            title: format!("{} {} on {}", r.family, r.protocol, r.port),
            interval_ms: args.interval,
            drives: addresses.iter().map(|&a| DriveView::new(a)).collect(),
            ..MonitorState::default()
        };
        let start = std::time::Instant::now();
        let mut ticker = tokio::time::interval(interval);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        if plain {
            let mut ever = false;
            loop {
                ticker.tick().await;
                refresh(&drives, &mut state, start).await;
                for d in &state.drives {
                    ever |= d.status.is_some();
                    if json {
                        println!("{}", plain_json(&state, d));
                    } else {
                        println!("{}", plain_line(&state, d));
                    }
                }
                if count.is_some_and(|n| state.refreshes >= n) {
                    break;
                }
            }
            if !ever {
                return Err(link_failure(format!(
                    "no answer from any drive on {} in {} refreshes: check the addresses, baud rate, serial format and wiring",
                    r.port, state.refreshes
                )));
            }
            return Ok(0);
        }
        live(&drives, &mut state, start, &mut ticker, count).await
    })
}

/// Restores the terminal when dropped, also on an error or a panic.
struct TerminalGuard;

impl Drop for TerminalGuard {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// What the key reader reports.
enum Key {
    Quit,
    Redraw,
}

async fn live(
    drives: &[Drive],
    state: &mut MonitorState,
    start: std::time::Instant,
    ticker: &mut tokio::time::Interval,
    count: Option<u64>,
) -> Result<u8> {
    let mut terminal =
        ratatui::try_init().map_err(|e| link_failure(format!("cannot set up the terminal: {e}")))?;
    let _guard = TerminalGuard;
    // Keys are read on their own thread (crossterm's reads block) and sent here.
    let (tx, mut keys) = tokio::sync::mpsc::unbounded_channel();
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let stop = stop.clone();
        std::thread::spawn(move || read_keys(&tx, &stop))
    };
    let result = async {
        loop {
            terminal.draw(|f| render(f, state))?;
            if count.is_some_and(|n| state.refreshes >= n) {
                return Ok(0);
            }
            tokio::select! {
                _ = async { ticker.tick().await; refresh(drives, state, start).await } => {}
                key = keys.recv() => match key {
                    Some(Key::Quit) | None => return Ok(0),
                    Some(Key::Redraw) => {}
                },
            }
        }
    }
    .await;
    stop.store(true, Ordering::Relaxed);
    let _ = reader.join();
    result
}

fn read_keys(tx: &tokio::sync::mpsc::UnboundedSender<Key>, stop: &AtomicBool) {
    use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
    while !stop.load(Ordering::Relaxed) {
        match event::poll(Duration::from_millis(100)) {
            Ok(false) => continue,
            Ok(true) => {}
            Err(_) => {
                let _ = tx.send(Key::Quit);
                return;
            }
        }
        let key = match event::read() {
            Ok(Event::Key(k)) if k.kind != KeyEventKind::Release => match k.code {
                KeyCode::Char('q') | KeyCode::Char('Q') | KeyCode::Esc => Key::Quit,
                KeyCode::Char('c') if k.modifiers.contains(KeyModifiers::CONTROL) => Key::Quit,
                _ => continue,
            },
            Ok(Event::Resize(..)) => Key::Redraw,
            Ok(_) => continue,
            Err(_) => Key::Quit,
        };
        let quit = matches!(key, Key::Quit);
        if tx.send(key).is_err() || quit {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivebus_drive::profile::Fault;
    use ratatui::backend::TestBackend;
    use ratatui::Terminal;

    fn status(address: u8, hz: f64, amps: f64, fault: Option<Fault>) -> DriveStatus {
        DriveStatus {
            address,
            running: hz > 0.0,
            direction: Some("forward".into()),
            output_hz: Some(hz),
            setpoint_hz: Some(40.0),
            current_a: Some(amps),
            fault,
            values: Vec::new(),
        }
    }

    fn screen(state: &MonitorState, w: u16, h: u16) -> Vec<String> {
        let mut terminal = Terminal::new(TestBackend::new(w, h)).unwrap();
        terminal.draw(|f| render(f, state)).unwrap();
        let buf = terminal.backend().buffer().clone();
        buf.content.chunks(w as usize).map(|row| row.iter().map(|c| c.symbol()).collect::<String>()).collect()
    }

    fn sample() -> MonitorState {
        let mut one = DriveView::new(1);
        for i in 0..10 {
            one.record(i as f64 * 0.5, Ok(status(1, 3.0 * i as f64, 0.4 * i as f64, None)), None);
        }
        let mut online = Health::default();
        online.online = true;
        let mut two = DriveView::new(7);
        two.record(
            1.0,
            Ok(status(7, 0.0, 0.0, Some(Fault { code: 2, text: "over-current".into() }))),
            Some(&online),
        );
        two.record(4.0, Err("no answer from drive 7".into()), Some(&Health::default()));
        MonitorState {
            title: "generic modbus-rtu on tcp://127.0.0.1:4001".into(),
            interval_ms: 500,
            now_s: 4.5,
            refreshes: 10,
            drives: vec![one, two],
            stats: BusStats {
                transactions: 123,
                replies: 120,
                timeouts: 3,
                checksum_errors: 1,
                retries: 2,
                broadcasts: 0,
                wire_seconds: 1.0,
                wire_bytes: 960,
                elapsed_seconds: 4.0,
                ..BusStats::default()
            },
        }
    }

    #[test]
    fn draws_drives_trend_and_bus() {
        let lines = screen(&sample(), 110, 24);
        let text = lines.join("\n");
        assert!(lines[0].contains("drivebus monitor") && lines[0].contains("every 500 ms"), "{text}");
        let row1 = lines.iter().find(|l| l.contains("│1 ")).expect("a row for drive 1");
        assert!(row1.contains("running") && row1.contains("27.00") && row1.contains("40.00"), "{row1}");
        assert!(row1.contains("3.6") && row1.contains("online") && row1.contains("0.0 s"), "{row1}");
        let row7 = lines.iter().find(|l| l.contains("│7 ")).expect("a row for drive 7");
        assert!(row7.contains("fault") && row7.contains("2 over-current"), "{row7}");
        assert!(row7.contains("OFFLINE") && row7.contains("3.5 s"), "{row7}");
        assert!(text.contains("drive 1 27.0 Hz 3.6 A"), "{text}");
        assert!(text.contains("transactions 123") && text.contains("timeouts 3"), "{text}");
        assert!(text.contains("checksum errors 1") && text.contains("retries 2"), "{text}");
        assert!(text.contains("utilization 25.0 %") && text.contains("drives online 1/2"), "{text}");
        // The trend of a rising frequency: the top row of its bars is narrower than the
        // bottom row, and the newest sample reaches the top.
        let top = lines.iter().position(|l| l.contains("drive 1 27.0 Hz")).unwrap();
        let end = lines.iter().position(|l| l.contains("drive 7 0.0 Hz")).unwrap();
        let bars = |l: &str| l.chars().skip(23).take(40).filter(|c| "▁▂▃▄▅▆▇█".contains(*c)).count();
        assert!(lines[top].contains('█'), "{text}");
        assert!(bars(&lines[top]) < bars(&lines[end - 1]), "{text}");
        assert!(bars(&lines[end - 1]) >= 8, "{text}");
    }

    #[test]
    fn at_80_columns_nothing_is_cut() {
        let mut st = sample();
        let long = "heat sink over temperature: let the drive cool and check its fan";
        st.drives[1].record(4.2, Ok(status(7, 0.0, 0.0, Some(Fault { code: 29, text: long.into() }))), None);
        let lines = screen(&st, 80, 30);
        let text = lines.join("\n");
        // The fault text whole, over as many lines of its column as it needs.
        let fault_col = lines.iter().filter(|l| l.starts_with('│')).cloned().collect::<Vec<_>>().join(" ");
        let want = format!("29 {long}");
        for w in want.split(' ') {
            assert!(fault_col.contains(w), "{w:?} is cut:\n{text}");
        }
        for needed in [
            "transactions 123  replies 120  timeouts 3  retries 2",
            "checksum errors 1  broadcasts 0",
            "utilization 25.0 % (1.00 s on the wire in 4.0 s)  drives online 2/2",
            "output Hz",
            "current A",
        ] {
            assert!(text.contains(needed), "{needed:?} is missing or cut:\n{text}");
        }
    }

    #[test]
    fn wrap_cuts_at_spaces_and_long_words() {
        assert_eq!(wrap("2 over-current", 20), ["2 over-current"]);
        assert_eq!(wrap("a bb ccc", 4), ["a bb", "ccc"]);
        assert_eq!(wrap("abcdefghij", 4), ["abcd", "efgh", "ij"]);
        assert_eq!(wrap("", 4), [""]);
    }

    #[test]
    fn small_terminals_do_not_panic() {
        for (w, h) in [(1, 1), (20, 5), (40, 10), (200, 3)] {
            let _ = screen(&sample(), w, h);
        }
        let _ = screen(&MonitorState::default(), 30, 8);
    }

    #[test]
    fn plain_lines_and_history() {
        let st = sample();
        let l1 = plain_line(&st, &st.drives[0]);
        assert!(
            l1.starts_with("t=4.5s drive=1 state=running dir=forward output_hz=27.00 setpoint_hz=40.00"),
            "{l1}"
        );
        assert!(l1.contains("online=yes age=0.0s"), "{l1}");
        let l7 = plain_line(&st, &st.drives[1]);
        assert!(
            l7.contains("fault=\"2 over-current\"") && l7.contains("online=no") && l7.contains("error="),
            "{l7}"
        );
        let j = plain_json(&st, &st.drives[1]);
        assert_eq!(j["address"], 7);
        assert_eq!(j["fault"]["code"], 2);
        let mut v = DriveView::new(3);
        for i in 0..HISTORY + 5 {
            v.record(i as f64, Ok(status(3, i as f64, 0.0, None)), None);
        }
        assert_eq!(v.hz.len(), HISTORY);
        assert_eq!(v.hz.front().copied(), Some(5.0));
    }

    #[test]
    fn json_times_carry_no_float_noise() {
        let mut st = sample();
        st.drives[0].record(4.5000039, Ok(status(1, 30.0, 1.0, None)), None);
        st.now_s = 4.5000078;
        let j = plain_json(&st, &st.drives[0]);
        assert_eq!((j["t"].as_f64(), j["age_s"].as_f64()), (Some(4.5), Some(0.0)), "{j}");
    }
}
