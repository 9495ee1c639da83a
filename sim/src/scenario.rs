//! Scripted stimuli: a scenario is a list of steps (presses, ramps, rests, remounts at another
//! curvature or orientation, temperature changes, contact moves) compiled into a timeline whose
//! force, temperature, mounting and contact are pure functions of time.

use serde::{Deserialize, Serialize};

use crate::SimError;

/// How the sensor is mounted: on a cylinder of curvature `curvature_m1`, rotated by a multiple
/// of 90 degrees (any whole degree when the model sets `curvature.any_angle`) and possibly
/// flipped face down.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Mounting {
    /// Curvature of the mounting surface (1/m); 0 is flat.
    pub curvature_m1: f64,
    /// Rotation of the sensor on the surface: 0, 90, 180 or 270 degrees (0..360 with the
    /// model's `curvature.any_angle`).
    pub rotation_deg: u32,
    /// Mounted face down.
    pub flipped: bool,
}

impl Default for Mounting {
    fn default() -> Self {
        Mounting {
            curvature_m1: 0.0,
            rotation_deg: 0,
            flipped: false,
        }
    }
}

/// Where the indenter touches, in node coordinates of the sensor: node `(r, c)` covers
/// `[r, r+1) x [c, c+1)`. The default is the central 2 x 2 block (the paper's indenter), or the
/// whole array when it is smaller.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Contact {
    /// Centre row coordinate (node units).
    pub row: f64,
    /// Centre column coordinate (node units).
    pub col: f64,
    /// Indenter height (node pitches).
    pub size_rows: f64,
    /// Indenter width (node pitches).
    pub size_cols: f64,
}

impl Contact {
    /// The central 2 x 2 block (or the whole array if smaller).
    pub fn central(rows: usize, cols: usize) -> Contact {
        Contact {
            row: rows as f64 / 2.0,
            col: cols as f64 / 2.0,
            size_rows: (rows as f64).min(2.0),
            size_cols: (cols as f64).min(2.0),
        }
    }

    /// Share of the force carried by each node (row-major): the overlap of the indenter with the
    /// node's cell over the indenter's area. Force outside the array is lost.
    pub fn weights(&self, rows: usize, cols: usize) -> Vec<f64> {
        let (r0, r1) = (
            self.row - self.size_rows / 2.0,
            self.row + self.size_rows / 2.0,
        );
        let (c0, c1) = (
            self.col - self.size_cols / 2.0,
            self.col + self.size_cols / 2.0,
        );
        let area = self.size_rows * self.size_cols;
        let overlap = |a0: f64, a1: f64, b0: f64, b1: f64| (a1.min(b1) - a0.max(b0)).max(0.0);
        let mut w = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                let o = overlap(r0, r1, r as f64, r as f64 + 1.0)
                    * overlap(c0, c1, c as f64, c as f64 + 1.0);
                w.push(if area > 0.0 { o / area } else { 0.0 });
            }
        }
        w
    }
}

/// Physiological tremor of a human hand pressing: two sinusoids, scaled by the force up to 1 N.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Tremor {
    /// Peak amplitude at 1 N or more (N).
    pub amplitude_n: f64,
    /// Main tremor frequency (Hz); a second component runs at 1.37 times it.
    pub freq_hz: f64,
}

impl Default for Tremor {
    fn default() -> Self {
        Tremor {
            amplitude_n: 0.05,
            freq_hz: 9.0,
        }
    }
}

fn d_ramp() -> f64 {
    0.5
}
fn d_hold() -> f64 {
    1.0
}
fn d_release() -> f64 {
    0.3
}
fn d_rest() -> f64 {
    1.0
}
fn d_size() -> f64 {
    2.0
}

/// One step of a scenario. Each step takes its durations' worth of time; force is held between
/// force steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Step {
    /// Nothing changes for `duration_s`.
    Rest { duration_s: f64 },
    /// Ramp up to `force_n`, hold, ramp down to zero, rest.
    Press {
        force_n: f64,
        #[serde(default = "d_ramp")]
        ramp_s: f64,
        #[serde(default = "d_hold")]
        hold_s: f64,
        #[serde(default = "d_release")]
        release_s: f64,
        #[serde(default = "d_rest")]
        rest_s: f64,
    },
    /// Ramp linearly to `force_n` over `duration_s` and stay there.
    Ramp { force_n: f64, duration_s: f64 },
    /// Remount the (unloaded) sensor: a new trial begins, then rest for `rest_s`.
    Mount {
        curvature_m1: f64,
        #[serde(default)]
        rotation_deg: u32,
        #[serde(default)]
        flipped: bool,
        #[serde(default = "d_rest")]
        rest_s: f64,
    },
    /// Ambient temperature ramps linearly to `temp_c` over `duration_s` (force held).
    Temperature { temp_c: f64, duration_s: f64 },
    /// Move the indenter (instantaneous; allowed only while unloaded).
    Contact {
        row: f64,
        col: f64,
        #[serde(default = "d_size")]
        size_rows: f64,
        #[serde(default = "d_size")]
        size_cols: f64,
    },
}

/// A scripted experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Scenario {
    /// Name, for logs.
    pub name: String,
    /// Frame rate (Hz).
    pub rate_hz: f64,
    /// Seed of every random draw (spread, noise, tremor phases).
    pub seed: u64,
    /// Start over at the end (for endless demos).
    pub repeat: bool,
    /// Mounting at the start (trial 0).
    pub mounting: Mounting,
    /// Ambient temperature at the start (degC).
    pub temp_c: f64,
    /// Indenter at the start (default: central 2 x 2 block).
    pub contact: Option<Contact>,
    /// Hand tremor while pressing (off when absent).
    pub tremor: Option<Tremor>,
    /// The steps, in order.
    #[serde(rename = "step")]
    pub steps: Vec<Step>,
}

impl Default for Scenario {
    fn default() -> Self {
        Scenario {
            name: "default".into(),
            rate_hz: 500.0,
            seed: 1,
            repeat: false,
            mounting: Mounting::default(),
            temp_c: 25.0,
            contact: None,
            tremor: None,
            steps: Vec::new(),
        }
    }
}

impl Scenario {
    /// Parses a scenario from TOML (steps as `[[step]]` tables with a `kind`).
    pub fn from_toml_str(text: &str) -> Result<Scenario, SimError> {
        let s: Scenario = toml::from_str(text).map_err(|e| SimError::Parse(e.to_string()))?;
        Ok(s)
    }

    /// The built-in demo: presses at 2, 4, 6 and 8 N with hand tremor, repeated forever, on a
    /// surface of the given curvature.
    pub fn demo(curvature_m1: f64, seed: u64) -> Scenario {
        let mut steps = vec![Step::Rest { duration_s: 1.0 }];
        for f in [2.0, 4.0, 6.0, 8.0] {
            steps.push(Step::Press {
                force_n: f,
                ramp_s: 0.6,
                hold_s: 2.0,
                release_s: 0.4,
                rest_s: 1.0,
            });
        }
        Scenario {
            name: "demo".into(),
            seed,
            repeat: true,
            mounting: Mounting {
                curvature_m1,
                ..Mounting::default()
            },
            tremor: Some(Tremor::default()),
            steps,
            ..Scenario::default()
        }
    }
}

/// A compiled scenario: breakpoints of piecewise-linear force and temperature, and the times at
/// which the mounting and contact change.
#[derive(Debug, Clone)]
pub struct Timeline {
    force: Vec<(f64, f64)>,
    temp: Vec<(f64, f64)>,
    mounts: Vec<(f64, Mounting)>,
    contacts: Vec<(f64, Contact)>,
    duration_s: f64,
    repeat: bool,
}

fn interp(points: &[(f64, f64)], t: f64) -> f64 {
    let i = points.partition_point(|p| p.0 <= t);
    if i == 0 {
        return points.first().map_or(0.0, |p| p.1);
    }
    if i >= points.len() {
        return points.last().map_or(0.0, |p| p.1);
    }
    let (t0, v0) = points[i - 1];
    let (t1, v1) = points[i];
    if t1 <= t0 {
        v1
    } else {
        v0 + (v1 - v0) * (t - t0) / (t1 - t0)
    }
}

fn step_index<T>(items: &[(f64, T)], t: f64) -> usize {
    items.partition_point(|p| p.0 <= t).saturating_sub(1)
}

fn nonneg(x: f64, what: &str, i: usize) -> Result<f64, SimError> {
    if x.is_finite() && x >= 0.0 {
        Ok(x)
    } else {
        Err(SimError::Invalid(format!(
            "step {}: {what} must be a finite number >= 0, got {x}",
            i + 1
        )))
    }
}

fn check_mounting(m: &Mounting, where_: &str, any_angle: bool) -> Result<(), SimError> {
    if !m.curvature_m1.is_finite() || m.curvature_m1 < 0.0 || m.curvature_m1 > 1000.0 {
        return Err(SimError::Invalid(format!(
            "{where_}: curvature_m1 must be in 0..=1000, got {}",
            m.curvature_m1
        )));
    }
    if any_angle {
        if m.rotation_deg >= 360 {
            return Err(SimError::Invalid(format!(
                "{where_}: rotation_deg must be 0..360 (curvature.any_angle), got {}",
                m.rotation_deg
            )));
        }
    } else if !matches!(m.rotation_deg, 0 | 90 | 180 | 270) {
        return Err(SimError::Invalid(format!(
            "{where_}: rotation_deg must be 0, 90, 180 or 270 (any whole degree with \
             curvature.any_angle), got {}",
            m.rotation_deg
        )));
    }
    Ok(())
}

fn check_contact(c: &Contact, where_: &str) -> Result<(), SimError> {
    let ok = [c.row, c.col, c.size_rows, c.size_cols]
        .iter()
        .all(|v| v.is_finite())
        && c.size_rows > 0.0
        && c.size_cols > 0.0;
    if ok {
        Ok(())
    } else {
        Err(SimError::Invalid(format!(
            "{where_}: contact needs finite row/col and positive size_rows/size_cols"
        )))
    }
}

impl Timeline {
    /// Compiles and validates a scenario for an array of `rows x cols`.
    pub fn compile(s: &Scenario, rows: usize, cols: usize) -> Result<Timeline, SimError> {
        Timeline::compile_with(s, rows, cols, false)
    }

    /// As [`Timeline::compile`]; with `any_angle` a mounting may have any rotation 0..360
    /// degrees (the model's `curvature.any_angle`).
    pub fn compile_with(
        s: &Scenario,
        rows: usize,
        cols: usize,
        any_angle: bool,
    ) -> Result<Timeline, SimError> {
        if !(s.rate_hz.is_finite() && s.rate_hz > 0.0 && s.rate_hz <= 100_000.0) {
            return Err(SimError::Invalid(format!(
                "rate_hz must be in (0, 100000], got {}",
                s.rate_hz
            )));
        }
        if !s.temp_c.is_finite() {
            return Err(SimError::Invalid("temp_c must be finite".into()));
        }
        check_mounting(&s.mounting, "mounting", any_angle)?;
        let contact0 = s.contact.unwrap_or_else(|| Contact::central(rows, cols));
        check_contact(&contact0, "contact")?;
        let mut t = 0.0;
        let mut f = 0.0;
        let mut temp = s.temp_c;
        let mut force = vec![(0.0, 0.0)];
        let mut temps = vec![(0.0, temp)];
        let mut mounts = vec![(0.0, s.mounting)];
        let mut contacts = vec![(0.0, contact0)];
        for (i, step) in s.steps.iter().enumerate() {
            match step {
                Step::Rest { duration_s } => {
                    t += nonneg(*duration_s, "duration_s", i)?;
                }
                Step::Press {
                    force_n,
                    ramp_s,
                    hold_s,
                    release_s,
                    rest_s,
                } => {
                    let peak = nonneg(*force_n, "force_n", i)?;
                    force.push((t, f));
                    t += nonneg(*ramp_s, "ramp_s", i)?;
                    force.push((t, peak));
                    t += nonneg(*hold_s, "hold_s", i)?;
                    force.push((t, peak));
                    t += nonneg(*release_s, "release_s", i)?;
                    force.push((t, 0.0));
                    t += nonneg(*rest_s, "rest_s", i)?;
                    f = 0.0;
                }
                Step::Ramp {
                    force_n,
                    duration_s,
                } => {
                    let to = nonneg(*force_n, "force_n", i)?;
                    force.push((t, f));
                    t += nonneg(*duration_s, "duration_s", i)?;
                    force.push((t, to));
                    f = to;
                }
                Step::Mount {
                    curvature_m1,
                    rotation_deg,
                    flipped,
                    rest_s,
                } => {
                    let mounting = &Mounting {
                        curvature_m1: *curvature_m1,
                        rotation_deg: *rotation_deg,
                        flipped: *flipped,
                    };
                    if f != 0.0 {
                        return Err(SimError::Invalid(format!(
                            "step {}: mount while loaded ({f} N); release first",
                            i + 1
                        )));
                    }
                    check_mounting(mounting, &format!("step {}", i + 1), any_angle)?;
                    mounts.push((t, *mounting));
                    t += nonneg(*rest_s, "rest_s", i)?;
                }
                Step::Temperature { temp_c, duration_s } => {
                    if !temp_c.is_finite() {
                        return Err(SimError::Invalid(format!(
                            "step {}: temp_c must be finite",
                            i + 1
                        )));
                    }
                    temps.push((t, temp));
                    t += nonneg(*duration_s, "duration_s", i)?;
                    temps.push((t, *temp_c));
                    temp = *temp_c;
                }
                Step::Contact {
                    row,
                    col,
                    size_rows,
                    size_cols,
                } => {
                    let contact = &Contact {
                        row: *row,
                        col: *col,
                        size_rows: *size_rows,
                        size_cols: *size_cols,
                    };
                    if f != 0.0 {
                        return Err(SimError::Invalid(format!(
                            "step {}: contact moved while loaded; release first",
                            i + 1
                        )));
                    }
                    check_contact(contact, &format!("step {}", i + 1))?;
                    contacts.push((t, *contact));
                }
            }
        }
        force.push((t, f));
        temps.push((t, temp));
        if s.repeat && (t <= 0.0 || f != 0.0) {
            return Err(SimError::Invalid(
                "repeat needs a scenario that lasts > 0 s and ends unloaded".into(),
            ));
        }
        Ok(Timeline {
            force,
            temp: temps,
            mounts,
            contacts,
            duration_s: t,
            repeat: s.repeat,
        })
    }

    /// Length of one pass (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Whether the timeline starts over at its end.
    pub fn repeats(&self) -> bool {
        self.repeat
    }

    fn wrap(&self, t: f64) -> f64 {
        if self.repeat && self.duration_s > 0.0 {
            t.rem_euclid(self.duration_s)
        } else {
            t
        }
    }

    /// Scripted total force at time `t` (N), without tremor.
    pub fn force_n(&self, t: f64) -> f64 {
        interp(&self.force, self.wrap(t))
    }

    /// Ambient temperature at time `t` (degC).
    pub fn temp_c(&self, t: f64) -> f64 {
        interp(&self.temp, self.wrap(t))
    }

    /// Mounting and trial index at time `t`. Repeats count on: pass `p` has trials
    /// `p * n_mounts ..`.
    pub fn mounting(&self, t: f64) -> (Mounting, u32) {
        let i = step_index(&self.mounts, self.wrap(t));
        let pass = if self.repeat && self.duration_s > 0.0 {
            (t / self.duration_s).floor().max(0.0) as u32
        } else {
            0
        };
        (
            self.mounts[i].1,
            pass.saturating_mul(self.mounts.len() as u32) + i as u32,
        )
    }

    /// Contact at time `t`.
    pub fn contact(&self, t: f64) -> Contact {
        self.contacts[step_index(&self.contacts, self.wrap(t))].1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn central_contact_covers_the_central_block() {
        let w = Contact::central(4, 4).weights(4, 4);
        for (k, wk) in w.iter().enumerate() {
            let expect = if [5, 6, 9, 10].contains(&k) {
                0.25
            } else {
                0.0
            };
            assert!((wk - expect).abs() < 1e-12, "node {k}: {wk}");
        }
        let w1 = Contact::central(1, 1).weights(1, 1);
        assert!((w1[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn press_profile_and_repeat() {
        let s = Scenario {
            repeat: true,
            steps: vec![Step::Press {
                force_n: 4.0,
                ramp_s: 1.0,
                hold_s: 1.0,
                release_s: 1.0,
                rest_s: 1.0,
            }],
            ..Scenario::default()
        };
        let tl = Timeline::compile(&s, 4, 4).expect("valid");
        assert_eq!(tl.duration_s(), 4.0);
        assert!((tl.force_n(0.5) - 2.0).abs() < 1e-12);
        assert!((tl.force_n(1.5) - 4.0).abs() < 1e-12);
        assert!((tl.force_n(3.5) - 0.0).abs() < 1e-12);
        assert!((tl.force_n(4.5) - 2.0).abs() < 1e-12, "repeats");
    }

    #[test]
    fn bad_steps_are_refused_with_their_position() {
        let s = Scenario {
            steps: vec![
                Step::Ramp {
                    force_n: 2.0,
                    duration_s: 1.0,
                },
                Step::Mount {
                    curvature_m1: 10.0,
                    rotation_deg: 0,
                    flipped: false,
                    rest_s: 1.0,
                },
            ],
            ..Scenario::default()
        };
        let e = Timeline::compile(&s, 4, 4).expect_err("mount while loaded");
        assert!(e.to_string().contains("step 2"), "{e}");
        let text = "[[step]]\nkind = \"press\"\nforce_n = -1\n";
        let s = Scenario::from_toml_str(text).expect("parses");
        assert!(Timeline::compile(&s, 4, 4).is_err());
        assert!(Scenario::from_toml_str("[[step]]\nkind = \"jump\"\n").is_err());
    }

    #[test]
    fn documented_example_and_shipped_scenarios_compile() {
        let doc = include_str!("../../docs/sim.md");
        let start = doc
            .find("```toml\nname = \"example\"")
            .expect("example in docs/sim.md")
            + 8;
        let end = start + doc[start..].find("```").expect("end of example");
        let s = Scenario::from_toml_str(&doc[start..end]).expect("documented example parses");
        let tl = Timeline::compile(&s, 4, 4).expect("documented example is valid");
        assert_eq!(tl.mounting(1e9).1, 1, "one remount");
        let sweep = include_str!("../../scenarios/calibration-sweep.toml");
        let s = Scenario::from_toml_str(sweep).expect("sweep parses");
        Timeline::compile(&s, 4, 4).expect("sweep is valid");
    }

    #[test]
    fn scenario_toml_round_trip() {
        let s = Scenario::demo(40.0, 3);
        let text = toml::to_string(&s).expect("serializes");
        let back = Scenario::from_toml_str(&text).expect("parses");
        assert_eq!(s, back);
    }
}
