//! Writes a calibration file in the same hand-editable layout as the shipped ones.

use std::fmt::Write as _;

use crate::calibration::{BlockSpec, CalibrationFile, ModelSpec};
use crate::dynamics::Domain;

fn fmt_f(x: f64) -> String {
    if x == x.trunc() && x.abs() < 1e15 {
        format!("{x:.1}")
    } else {
        format!("{x:e}")
    }
}

/// Numbers in exponent form, comma separated (exact round trip).
fn list(v: &[f64]) -> String {
    v.iter()
        .map(|a| format!("{a:e}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn write_block(out: &mut String, header: &str, b: &BlockSpec) {
    let _ = writeln!(out, "\n{header}");
    let _ = writeln!(out, "name = {:?}", b.name);
    if let Some(nodes) = &b.nodes {
        let list: Vec<String> = nodes.iter().map(|k| k.to_string()).collect();
        let _ = writeln!(out, "nodes = [{}]", list.join(", "));
    }
    match &b.model {
        ModelSpec::Poly { terms } => {
            let _ = writeln!(out, "model = {{ form = \"poly\", terms = [");
            for t in terms {
                let _ = writeln!(
                    out,
                    "  {{ s = {}, c = {}, coef = {:e} }},",
                    t.s, t.c, t.coef
                );
            }
            let _ = writeln!(out, "] }}");
        }
        ModelSpec::Physics {
            curvature_gain,
            x,
            f,
        } => {
            let _ = writeln!(
                out,
                "model = {{ form = \"physics\", curvature_gain = [{:e}, {:e}],\n  x = [{}],\n  f = [{}] }}",
                curvature_gain[0],
                curvature_gain[1],
                list(x),
                list(f)
            );
        }
        ModelSpec::Monotone { curvature_m1, f, s } => {
            let rows: Vec<String> = s.iter().map(|r| format!("    [{}]", list(r))).collect();
            let _ = writeln!(
                out,
                "model = {{ form = \"monotone\", curvature_m1 = [{}],\n  f = [{}],\n  s = [\n{}\n  ] }}",
                list(curvature_m1),
                list(f),
                rows.join(",\n")
            );
        }
    }
    let r = &b.range;
    let _ = write!(
        out,
        "range = {{ s = [{}, {}], curvature_m1 = [{}, {}]",
        fmt_f(r.s[0]),
        fmt_f(r.s[1]),
        fmt_f(r.curvature_m1[0]),
        fmt_f(r.curvature_m1[1])
    );
    if !r.s_max_by_curvature.is_empty() {
        let pts: Vec<String> = r
            .s_max_by_curvature
            .iter()
            .map(|p| format!("[{}, {}]", fmt_f(p[0]), fmt_f(p[1])))
            .collect();
        let _ = write!(out, ", s_max_by_curvature = [{}]", pts.join(", "));
    }
    let _ = writeln!(out, " }}");
    if let Some(c) = &b.creep {
        let domain = match c.domain {
            Domain::Reading => String::new(),
            d => format!(", domain = {:?}", d.name()),
        };
        let _ = writeln!(
            out,
            "creep = {{ tau_s = [{}], share = [{}]{domain} }}",
            list(&c.tau_s),
            list(&c.share)
        );
    }
    if let Some(h) = &b.hysteresis {
        let _ = writeln!(
            out,
            "hysteresis = {{ threshold_n = [{}], weight = [{}] }}",
            list(&h.threshold_n),
            list(&h.weight)
        );
    }
}

/// Renders a calibration file in the same hand-editable layout as the shipped ones.
pub fn to_toml(f: &CalibrationFile, comment: &str) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        let _ = writeln!(out, "# {line}");
    }
    let _ = writeln!(out, "id = {:?}", f.id);
    let _ = writeln!(out, "version = {}", f.version);
    if !f.description.is_empty() {
        let _ = writeln!(out, "description = {:?}", f.description);
    }
    let _ = writeln!(out, "rows = {}", f.rows);
    let _ = writeln!(out, "cols = {}", f.cols);
    let _ = writeln!(
        out,
        "default_curvature_m1 = {}",
        fmt_f(f.default_curvature_m1)
    );
    let r = &f.readout;
    let _ = writeln!(
        out,
        "readout = {{ kind = {:?}, full_scale = {}, rises = {} }}",
        r.kind.name(),
        fmt_f(r.full_scale),
        r.rises
    );
    if !f.no_load_reading.is_empty() {
        let list: Vec<String> = f
            .no_load_reading
            .iter()
            .map(|v| format!("{v:.3}"))
            .collect();
        let _ = writeln!(out, "no_load_reading = [{}]", list.join(", "));
    }
    if f.no_load_force_n != 0.0 {
        let _ = writeln!(out, "no_load_force_n = {:e}", f.no_load_force_n);
    }
    write_block(&mut out, "[array]", &f.array);
    for b in &f.blocks {
        write_block(&mut out, "[[block]]", b);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::{Calibration, RangeSpec, Term};
    use taxel_formats::{Readout, ReadoutKind};

    fn block(name: &str, nodes: Option<Vec<usize>>, model: ModelSpec) -> BlockSpec {
        BlockSpec {
            name: name.into(),
            nodes,
            model,
            range: RangeSpec {
                s: [0.0, 500.0],
                curvature_m1: [0.0, 80.0],
                s_max_by_curvature: vec![],
            },
            creep: None,
            hysteresis: None,
        }
    }

    #[test]
    fn rendered_file_parses_back() {
        let f = CalibrationFile {
            id: "t".into(),
            version: 2,
            description: "d".into(),
            rows: 2,
            cols: 2,
            default_curvature_m1: 0.0,
            readout: Readout::new(ReadoutKind::Divider, 4095.0),
            no_load_reading: vec![450.0, 512.5, 600.0, 700.25],
            no_load_force_n: 0.5,
            array: block(
                "array",
                None,
                ModelSpec::Poly {
                    terms: vec![Term {
                        s: 1,
                        c: 0,
                        coef: 0.01,
                    }],
                },
            ),
            blocks: vec![block(
                "center",
                Some(vec![0, 3]),
                ModelSpec::Monotone {
                    curvature_m1: vec![0.0, 80.0],
                    f: vec![0.0, 1.0, 5.0],
                    s: vec![vec![0.0, 10.0, 40.0], vec![0.0, 5.0, 21.5]],
                },
            )],
        };
        let text = to_toml(&f, "hello\nworld");
        let back: CalibrationFile = toml::from_str(&text).expect("parses");
        assert_eq!(back, f);
        Calibration::from_file("t", &back).expect("valid");
    }
}
