//! Drawing the monitor: sensor tabs, the array heatmap, curvature, forces with sparklines,
//! calibration, rate, sample ages and drops, process health, and the key help line.

use std::time::Instant;

use ratatui::layout::{Alignment, Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Paragraph, Sparkline, Tabs};
use ratatui::Frame;
use taxel_msgs::force_flags;

use super::state::{Health, Procs, SensorState, View};
use super::Model;

/// A blue -> green -> yellow -> red ramp of the 256-colour palette (works over SSH in any
/// terminal with 256 colours).
const RAMP: [u8; 16] = [
    17, 18, 19, 25, 31, 37, 36, 35, 34, 70, 106, 142, 178, 214, 208, 196,
];

pub(crate) fn draw(f: &mut Frame, m: &Model) {
    let [top, body, procs, help] = Layout::vertical([
        Constraint::Length(3),
        Constraint::Min(14),
        Constraint::Length(procs_height(m, f.area().width)),
        Constraint::Length(1),
    ])
    .areas(f.area());
    draw_tabs(f, top, m);
    match m.sensors.get(m.selected) {
        Some(s) => draw_sensor(f, body, s, m.view),
        None => f.render_widget(
            Paragraph::new(format!(
                "waiting for sensors: no raw stream under prefix {:?} yet",
                m.prefix
            ))
            .block(Block::default().borders(Borders::ALL)),
            body,
        ),
    }
    draw_procs(f, procs, m);
    f.render_widget(
        Paragraph::new(
            "Tab/arrows/1-9 sensor   v view (raw counts / baseline-subtracted / force)   q quit",
        )
        .style(Style::default().add_modifier(Modifier::DIM)),
        help,
    );
}

fn draw_tabs(f: &mut Frame, area: Rect, m: &Model) {
    let titles: Vec<String> = m
        .sensors
        .iter()
        .enumerate()
        .map(|(i, s)| format!("{} {}", i + 1, s.id))
        .collect();
    let up = m.started.elapsed().as_secs();
    let tabs = Tabs::new(titles)
        .select(m.selected)
        .highlight_style(Style::default().add_modifier(Modifier::REVERSED))
        .block(Block::default().borders(Borders::ALL).title(format!(
            " taxel monitor | prefix {} | {} sensor(s){} | up {}:{:02} ",
            m.prefix,
            m.sensors.len(),
            if m.fixed { "" } else { " (auto)" },
            up / 60,
            up % 60
        )));
    f.render_widget(tabs, area);
}

fn fmt_num(v: f32) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    let a = v.abs();
    if a >= 1000.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn draw_sensor(f: &mut Frame, area: Rect, s: &SensorState, view: View) {
    let [left, right] =
        Layout::horizontal([Constraint::Length(46), Constraint::Min(30)]).areas(area);
    draw_heatmap(f, left, s, view);
    let [stats, spark] = Layout::vertical([Constraint::Length(9), Constraint::Min(4)]).areas(right);
    draw_stats(f, stats, s);
    draw_sparklines(f, spark, s);
}

fn draw_heatmap(f: &mut Frame, area: Rect, s: &SensorState, view: View) {
    let block = Block::default().borders(Borders::ALL).title(format!(
        " {} | view: {} ",
        s.id,
        view.label()
    ));
    let inner = block.inner(area);
    f.render_widget(block, area);
    let Some((rows, cols, values)) = s.heatmap(view) else {
        f.render_widget(Paragraph::new("no raw frame yet"), inner);
        return;
    };
    let finite = values.iter().copied().filter(|v| v.is_finite());
    let lo = finite.clone().fold(f32::INFINITY, f32::min);
    let hi = finite.fold(f32::NEG_INFINITY, f32::max);
    let legend = if lo.is_finite() {
        format!("scale {} .. {}", fmt_num(lo), fmt_num(hi))
    } else {
        "no baseline yet (needs a curvature estimate)".into()
    };
    let cell_w = ((inner.width as usize).saturating_sub(1) / cols.max(1)).clamp(3, 9) as u16;
    let cell_h = ((inner.height as usize).saturating_sub(2) / rows.max(1)).clamp(1, 3) as u16;
    for r in 0..rows {
        for c in 0..cols {
            let v = values[r * cols + c];
            let x = inner.x + c as u16 * cell_w;
            let y = inner.y + r as u16 * cell_h;
            if x + cell_w > inner.right() || y + cell_h > inner.bottom().saturating_sub(1) {
                continue;
            }
            let bg = if v.is_finite() && hi > lo {
                let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
                Color::Indexed(RAMP[(t * (RAMP.len() - 1) as f32).round() as usize])
            } else if v.is_finite() {
                Color::Indexed(RAMP[0])
            } else {
                Color::Reset
            };
            let text = fmt_num(v);
            let mut lines = vec![Line::from(""); cell_h as usize];
            lines[(cell_h as usize - 1) / 2] = Line::from(text);
            f.render_widget(
                Paragraph::new(lines)
                    .alignment(Alignment::Center)
                    .style(Style::default().bg(bg).fg(Color::White)),
                Rect::new(x, y, cell_w.saturating_sub(1), cell_h),
            );
        }
    }
    let ly = (inner.y + rows as u16 * cell_h).min(inner.bottom().saturating_sub(1));
    f.render_widget(
        Paragraph::new(format!("{rows} x {cols}, {legend}")),
        Rect::new(inner.x, ly, inner.width, 1),
    );
}

fn ago(t: Option<Instant>) -> String {
    match t {
        Some(t) => format!("{:.1} s ago", t.elapsed().as_secs_f64()),
        None => "never".into(),
    }
}

fn draw_stats(f: &mut Frame, area: Rect, s: &SensorState) {
    let mut lines = Vec::new();
    lines.push(Line::from(format!(
        "rate {:.1} Hz | frames {} | dropped {} | gaps flagged {}",
        s.rate_hz, s.frames, s.dropped, s.gaps_flagged
    )));
    lines.push(Line::from(match s.age_us {
        Some(([p50, p90, p99, max], n)) => format!(
            "age capture->force (us, {n} in 2 s): p50 {p50:.0} p90 {p90:.0} p99 {p99:.0} max {max:.0}"
        ),
        None => "sample age: no force samples in the last window".into(),
    }));
    lines.push(Line::from(match &s.curvature {
        Some(c) => format!(
            "curvature {} +/- {} 1/m (model {:08x}, {} frames, {})",
            fmt_num(c.curvature_m1),
            fmt_num(c.curvature_sd_m1),
            c.model_version,
            c.window_frames,
            ago(s.last_curvature)
        ),
        None => "curvature: no estimate yet".into(),
    }));
    match &s.force {
        Some(fs) => {
            lines.push(Line::from(format!(
                "force {} N | reading {} | curvature used {} 1/m (model {:08x})",
                fmt_num(fs.total_force_n),
                fmt_num(fs.total_reading),
                fmt_num(fs.curvature_m1),
                fs.curvature_model_version
            )));
            let reload = match s.cal_seen {
                Some((_, Some(t))) => format!("reloaded {}", ago(Some(t))),
                _ => "loaded before the monitor started".into(),
            };
            lines.push(Line::from(format!(
                "calibration v{} gen {} | {reload}",
                fs.cal_version, fs.cal_generation
            )));
            let mut flags = Vec::new();
            for (bit, name) in [
                (force_flags::SATURATED, "saturated"),
                (force_flags::OUT_OF_RANGE, "out-of-range"),
                (force_flags::CURVATURE_STALE, "curvature-stale"),
                (force_flags::CURVATURE_DEFAULTED, "curvature-defaulted"),
                (force_flags::NO_BASELINE, "no-baseline"),
                (force_flags::GAP_BEFORE, "gap"),
                (
                    force_flags::BASELINE_FROM_CALIBRATION,
                    "baseline-from-calibration",
                ),
                (force_flags::DYNAMICS_WARMING, "dynamics-warming"),
            ] {
                if fs.flags & bit != 0 {
                    flags.push(name);
                }
            }
            let flags = if flags.is_empty() {
                "none".to_string()
            } else {
                flags.join(", ")
            };
            lines.push(Line::from(vec![
                Span::raw("flags: "),
                Span::styled(flags, Style::default().fg(Color::Yellow)),
            ]));
        }
        None => lines.push(Line::from(
            "force: no sample yet (is a calibrator running?)",
        )),
    }
    lines.push(Line::from(format!(
        "last raw {} | last force {}",
        ago(s.last_raw),
        ago(s.last_force)
    )));
    f.render_widget(
        Paragraph::new(lines).block(Block::default().borders(Borders::ALL).title(" stream ")),
        area,
    );
}

fn draw_sparklines(f: &mut Frame, area: Rect, s: &SensorState) {
    let block = Block::default()
        .borders(Borders::ALL)
        .title(" force per block (N), last 240 samples ");
    let inner = block.inner(area);
    f.render_widget(block, area);
    let mut series: Vec<(String, Vec<f32>)> = vec![(
        "total".into(),
        s.total_history.iter().copied().collect::<Vec<_>>(),
    )];
    for (i, h) in s.block_history.iter().enumerate() {
        series.push((format!("b{i}"), h.iter().copied().collect()));
    }
    let max_rows = inner.height as usize;
    for (k, (name, vals)) in series.iter().take(max_rows).enumerate() {
        let y = inner.y + k as u16;
        let last = vals.last().copied().unwrap_or(f32::NAN);
        let label = format!("{name:>5} {:>7} ", fmt_num(last));
        let lw = label.len() as u16;
        f.render_widget(Paragraph::new(label), Rect::new(inner.x, y, lw, 1));
        let w = inner.width.saturating_sub(lw) as usize;
        let hi = vals
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max);
        let data: Vec<u64> = vals
            .iter()
            .skip(vals.len().saturating_sub(w))
            .map(|v| {
                if v.is_finite() && hi > 0.0 {
                    (v.max(0.0) / hi * 100.0) as u64
                } else {
                    0
                }
            })
            .collect();
        f.render_widget(
            Sparkline::default()
                .data(&data)
                .max(100)
                .style(Style::default().fg(Color::Cyan)),
            Rect::new(inner.x + lw, y, w as u16, 1),
        );
    }
}

/// Width of one entry of the process panel.
const CELL: usize = 38;

fn draw_procs(f: &mut Frame, area: Rect, m: &Model) {
    let now = Instant::now();
    let stream_of = |name: &str| -> Option<Option<Instant>> {
        let (role, sensor) = name.split_once('-')?;
        let s = m.sensors.iter().find(|s| s.id == sensor)?;
        match role {
            "publisher" => Some(s.last_raw),
            "calibrator" => Some(s.last_force),
            _ => None,
        }
    };
    // Entries in columns of CELL characters: name (15 + 1), health (10 + 1), pid (7), restarts
    // (" r<n>", 3) and a 1-character gap.
    let per_row = ((area.width as usize).saturating_sub(2) / CELL).max(1);
    let mut lines: Vec<Line> = Vec::new();
    let mut row: Vec<Span> = Vec::new();
    for (i, p) in m.procs.by_name.values().enumerate() {
        let h = Procs::health(p, stream_of(&p.name), now);
        let color = match h {
            Health::Alive => Color::Green,
            Health::Stale => Color::Yellow,
            _ => Color::Red,
        };
        row.push(Span::raw(format!("{:<15} ", p.name)));
        row.push(Span::styled(
            format!("{:<10} ", h.label()),
            Style::default().fg(color),
        ));
        row.push(Span::raw(format!("{:<7}", p.pid)));
        row.push(Span::raw(if p.restarts > 0 {
            format!(" r{:<1} ", p.restarts)
        } else {
            "    ".into()
        }));
        if (i + 1) % per_row == 0 {
            lines.push(Line::from(std::mem::take(&mut row)));
        }
    }
    if !row.is_empty() {
        lines.push(Line::from(row));
    }
    if lines.is_empty() {
        lines.push(Line::from("no iceoryx2 node under the prefix"));
    }
    f.render_widget(
        Paragraph::new(lines).block(
            Block::default().borders(Borders::ALL).title(
                " processes: name, health, pid, restarts (iceoryx2 nodes under the prefix) ",
            ),
        ),
        area,
    );
}

/// Lines the process panel needs (borders included).
pub(crate) fn procs_height(m: &Model, width: u16) -> u16 {
    let per_row = ((width as usize).saturating_sub(2) / CELL).max(1);
    let n = m.procs.by_name.len().max(1);
    (n.div_ceil(per_row) + 2).min(12) as u16
}
