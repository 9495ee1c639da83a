//! `taxel monitor`: a terminal UI (ratatui + crossterm) that works over SSH. It subscribes like
//! any other consumer to the raw, curvature and force streams of each sensor (discovered from
//! iceoryx2's service listing under the prefix when `--sensor` is not given), lists the
//! prefix's nodes once a second for process health, and redraws at `--fps` (15 by default).
//! Keys: Tab / arrows / 1..9 switch sensor, `v` cycles the heatmap view, `q`, Esc or Ctrl-C
//! quit and restore the terminal; SIGINT/SIGTERM do too.

pub mod state;
mod ui;

use std::io::Stdout;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc as iox;
use ratatui::backend::CrosstermBackend;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::crossterm::{cursor, execute, terminal};
use ratatui::Terminal;
use taxel_msgs::{CurvatureEstimate, ForceSample, RawFrame, Stream};
use taxel_runtime::ipc::{Ipc, StreamSubscriber};
use taxel_runtime::process::{exit_code, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;

use state::{NodeSeen, Procs, SensorState, View};

/// Live terminal monitor of the sensors and processes under a prefix.
#[derive(Debug, Parser)]
#[command(name = "taxel-monitor", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Sensors to show (repeat or separate with commas); default: every sensor with a raw
    /// stream under the prefix, discovered while running.
    #[arg(long = "sensor", value_delimiter = ',', num_args = 1..)]
    pub sensors: Vec<String>,
    /// Redraws per second.
    #[arg(long, default_value_t = 15.0)]
    pub fps: f64,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
}

pub fn main(args: Args) -> ExitCode {
    // No tracing subscriber: log lines would tear the screen. Errors are printed after the
    // terminal is restored.
    exit_code("taxel-monitor", run(&args))
}

struct Subs {
    raw: StreamSubscriber<RawFrame>,
    curvature: StreamSubscriber<CurvatureEstimate>,
    force: StreamSubscriber<ForceSample>,
}

/// What the UI draws from.
pub(crate) struct Model {
    pub prefix: String,
    pub sensors: Vec<SensorState>,
    pub selected: usize,
    pub view: View,
    pub procs: Procs,
    pub started: Instant,
    pub fixed: bool,
}

/// Puts the terminal back as it was, also on an early return or a panic.
struct TerminalGuard;

impl TerminalGuard {
    fn enter() -> anyhow::Result<(TerminalGuard, Terminal<CrosstermBackend<Stdout>>)> {
        terminal::enable_raw_mode().context("terminal: cannot enter raw mode (not a tty?)")?;
        let guard = TerminalGuard;
        let mut out = std::io::stdout();
        execute!(out, terminal::EnterAlternateScreen, cursor::Hide)
            .context("terminal: cannot switch to the alternate screen")?;
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            restore();
            hook(info);
        }));
        let term = Terminal::new(CrosstermBackend::new(out)).context("terminal")?;
        Ok((guard, term))
    }
}

fn restore() {
    let _ = terminal::disable_raw_mode();
    let _ = execute!(
        std::io::stdout(),
        terminal::LeaveAlternateScreen,
        cursor::Show
    );
}

impl Drop for TerminalGuard {
    fn drop(&mut self) {
        restore();
    }
}

fn validate(a: &Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.fps.is_finite() && (0.5..=60.0).contains(&a.fps),
        "--fps must be between 0.5 and 60, got {}",
        a.fps
    );
    if let Some(s) = a.seconds {
        anyhow::ensure!(
            s.is_finite() && s > 0.0,
            "--seconds must be positive, got {s}"
        );
    }
    for s in &a.sensors {
        taxel_msgs::sensor_id_bytes(s).map_err(|e| anyhow::anyhow!("--sensor {s:?}: {e}"))?;
    }
    Ok(())
}

/// Sensor ids with a raw stream under the prefix.
fn discover(config: &iceoryx2::config::Config) -> Vec<String> {
    let mut found = Vec::new();
    let _ = iox::Service::list(config, |s| {
        let name = s.static_details.name().as_str();
        if let Some(id) = name
            .strip_prefix("taxel/")
            .and_then(|r| r.strip_suffix("/raw"))
        {
            if !id.contains('/') && !found.iter().any(|f: &String| f == id) {
                found.push(id.to_string());
            }
        }
        CallbackProgression::Continue
    });
    found.sort();
    found
}

fn list_nodes(config: &iceoryx2::config::Config, own: &str) -> Vec<NodeSeen> {
    let mut out = Vec::new();
    let _ = Node::<iox::Service>::list(config, |state| {
        let (view_alive, details, id) = match &state {
            NodeState::Alive(v) => (true, v.details().clone(), v.id().to_string()),
            NodeState::Dead(v) => (false, v.details().clone(), v.id().to_string()),
            _ => return CallbackProgression::Continue,
        };
        if let Some(d) = details {
            let name = d.name().as_str().to_string();
            if name != own {
                out.push(NodeSeen {
                    name,
                    pid: d.process_id().value() as u32,
                    id,
                    alive: view_alive,
                });
            }
        }
        CallbackProgression::Continue
    });
    out
}

fn run(a: &Args) -> Result<(), Failure> {
    validate(a).config_err()?;
    let shutdown = Shutdown::install().runtime_err()?;
    let own = format!("monitor-{}", std::process::id());
    let ipc = Ipc::open(&a.common.prefix, &own).runtime_err()?;
    let t0 = Instant::now();
    let mut model = Model {
        prefix: a.common.prefix.clone(),
        sensors: Vec::new(),
        selected: 0,
        view: View::Raw,
        procs: Procs::default(),
        started: t0,
        fixed: !a.sensors.is_empty(),
    };
    let mut subs: Vec<Subs> = Vec::new();
    let add = |id: &str, model: &mut Model, subs: &mut Vec<Subs>| -> anyhow::Result<()> {
        subs.push(Subs {
            raw: ipc.subscriber(id, Stream::Raw)?,
            curvature: ipc.subscriber(id, Stream::Curvature)?,
            force: ipc.subscriber(id, Stream::Force)?,
        });
        model.sensors.push(SensorState::new(id, Instant::now()));
        Ok(())
    };
    for s in &a.sensors {
        add(s, &mut model, &mut subs).runtime_err()?;
    }
    let (guard, mut term) = TerminalGuard::enter().runtime_err()?;
    let frame_period = Duration::from_secs_f64(1.0 / a.fps);
    let end = a.seconds.map(|s| t0 + Duration::from_secs_f64(s));
    let mut next_draw = t0;
    let mut next_scan = t0;
    loop {
        if shutdown.requested() || end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        let now = Instant::now();
        if now >= next_scan {
            next_scan = now + Duration::from_secs(1);
            if !model.fixed {
                for id in discover(&ipc.config) {
                    if !model.sensors.iter().any(|s| s.id == id) {
                        add(&id, &mut model, &mut subs).runtime_err()?;
                    }
                }
            }
            let nodes = list_nodes(&ipc.config, &own);
            model.procs.update(&nodes, now);
        }
        for (s, sub) in model.sensors.iter_mut().zip(&subs) {
            let now = Instant::now();
            sub.raw.drain(|f| s.on_raw(f, now)).runtime_err()?;
            sub.curvature
                .drain(|e| s.on_curvature(e, now))
                .runtime_err()?;
            sub.force.drain(|f| s.on_force(f, now)).runtime_err()?;
        }
        let now = Instant::now();
        if now >= next_draw {
            next_draw = now + frame_period;
            for s in &mut model.sensors {
                s.tick(now);
            }
            term.draw(|f| ui::draw(f, &model))
                .context("terminal: draw")
                .runtime_err()?;
        }
        // Keys; the poll timeout paces the receive loop (5 ms, well inside the subscribers'
        // 256-sample raw and force buffers at 1 kHz).
        if event::poll(Duration::from_millis(5))
            .context("terminal: read keys")
            .runtime_err()?
        {
            if let Event::Key(k) = event::read().context("terminal: read keys").runtime_err()? {
                if k.kind != KeyEventKind::Press {
                    continue;
                }
                let n = model.sensors.len().max(1);
                match k.code {
                    KeyCode::Char('q') | KeyCode::Esc => break,
                    KeyCode::Char('c') if k.modifiers.contains(KeyModifiers::CONTROL) => break,
                    KeyCode::Char('v') => model.view = model.view.next(),
                    KeyCode::Tab | KeyCode::Right | KeyCode::Down => {
                        model.selected = (model.selected + 1) % n
                    }
                    KeyCode::BackTab | KeyCode::Left | KeyCode::Up => {
                        model.selected = (model.selected + n - 1) % n
                    }
                    KeyCode::Char(c @ '1'..='9') => {
                        let i = c as usize - '1' as usize;
                        if i < model.sensors.len() {
                            model.selected = i;
                        }
                    }
                    _ => {}
                }
                next_draw = Instant::now();
            }
        }
    }
    drop(term);
    drop(guard);
    for s in &model.sensors {
        println!(
            "taxel monitor: {} {} frames, {} dropped",
            s.id, s.frames, s.dropped
        );
    }
    Ok(())
}
