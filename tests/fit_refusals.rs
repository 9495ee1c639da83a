//! `taxel calibrator fit` never writes a calibration that cannot be right: a recording without
//! a force column, a readout that goes the wrong way, a load that never comes off, and readings
//! that do not follow the force are refused with one line naming the cause and a non-zero exit,
//! and no file is written (unless --accept-poor-fit asks for it).

use std::path::{Path, PathBuf};

use taxel_testkit::{pipeline, Pipeline};

/// A one-node session at 50 Hz: rests and presses of 2..10 N; `reading(F, i)` per frame.
fn session(dir: &Path, name: &str, rest_n: f64, reading: impl Fn(f64, usize) -> f64) -> PathBuf {
    let mut text = String::from("t_s,n0,force_n\n");
    let mut i = 0usize;
    let mut push = |f: f64, frames: usize, text: &mut String| {
        for _ in 0..frames {
            text.push_str(&format!(
                "{:.3},{:.0},{f:.4}\n",
                i as f64 / 50.0,
                reading(f, i)
            ));
            i += 1;
        }
    };
    for f in [2.0, 4.0, 6.0, 8.0, 10.0, 3.0, 7.0, 5.0] {
        push(rest_n, 100, &mut text);
        for k in 1..=25 {
            push(rest_n + (f - rest_n) * k as f64 / 25.0, 1, &mut text);
        }
        push(f, 100, &mut text);
    }
    push(rest_n, 100, &mut text);
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write");
    p
}

/// A small deterministic jitter in [-1, 1].
fn jitter(i: usize) -> f64 {
    ((i.wrapping_mul(2_654_435_761) % 1000) as f64 / 500.0) - 1.0
}

fn fit(p: &Pipeline, args: &[&str]) -> (i32, String, String) {
    let mut all = vec!["calibrator", "fit", "--flat"];
    all.extend_from_slice(args);
    p.run(&all)
}

fn refused(p: &Pipeline, args: &[&str], out: &Path, needle: &str) {
    let (code, _stdout, err) = fit(p, args);
    assert_ne!(code, 0, "{args:?} was accepted");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{args:?}: not one line:\n{err}");
    assert!(lines[0].contains(needle), "{args:?}: {err}");
    assert!(!out.exists(), "{args:?} wrote {}", out.display());
}

#[test]
fn bad_fits_are_refused_with_their_cause_and_nothing_is_written() {
    let p = pipeline!("fitrefusal");
    let dir = p.dir();
    let out = p.path("cal.toml");
    let out_s = out.display().to_string();
    // Ohms that fall with force.
    let ohms = session(dir, "ohms.csv", 0.0, |f, i| {
        2000.0 / (1.0 + 0.8 * f) + 2.0 * jitter(i)
    });
    let ohms_s = ohms.display().to_string();

    // A good session is fitted, and auto says which readout it decided and why.
    let (code, stdout, err) = fit(&p, &["--data", &ohms_s, "--out", &out_s]);
    assert_eq!(code, 0, "{err}");
    assert!(
        stdout
            .lines()
            .any(|l| l.starts_with("readout auto:") && l.contains("fall")),
        "{stdout}"
    );
    assert!(out.exists());
    std::fs::remove_file(&out).expect("rm");

    // The wrong readout direction.
    refused(
        &p,
        &["--data", &ohms_s, "--out", &out_s, "--readout", "amplifier"],
        &out,
        "wrong readout direction",
    );

    // No force column.
    let bare = dir.join("bare.csv");
    std::fs::write(&bare, "t_s,n0\n0,100\n0.02,101\n0.04,99\n").expect("write");
    refused(
        &p,
        &["--data", &bare.display().to_string(), "--out", &out_s],
        &out,
        "force_n",
    );

    // A constant load that never comes off while the reading creeps (like a creep run).
    let mut text = String::from("t_s,n0,force_n\n");
    for i in 0..3000 {
        let t = i as f64 / 50.0;
        let ohm = 270.0 + 1175.0 * (-t / 15.0).exp() + 2.0 * jitter(i);
        text.push_str(&format!(
            "{t:.3},{ohm:.0},{:.4}\n",
            0.98 + 0.005 * jitter(i + 7)
        ));
    }
    let hold = dir.join("hold.csv");
    std::fs::write(&hold, text).expect("write");
    refused(
        &p,
        &["--data", &hold.display().to_string(), "--out", &out_s],
        &out,
        "no unloaded frames",
    );

    // Readings that do not follow the force: refused, unless asked for.
    let noise = session(dir, "noise.csv", 0.0, |_, i| 500.0 + 50.0 * jitter(i));
    let noise_s = noise.display().to_string();
    refused(
        &p,
        &["--data", &noise_s, "--out", &out_s],
        &out,
        "--accept-poor-fit",
    );
    let (code, _, err) = fit(
        &p,
        &["--data", &noise_s, "--out", &out_s, "--accept-poor-fit"],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.exists());
}
