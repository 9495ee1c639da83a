//! Processes that serve several sensors: the sensor list of `--sensor a,b,c` (valid ids, none
//! twice) and per-sensor options ([`PerSensor`]), which take one value for every sensor or a
//! comma-separated list with one value per sensor (`--calibration a.toml,b.toml`). A single
//! sensor and a single value behave exactly as before lists existed.

use std::fmt::Display;
use std::str::FromStr;

/// Most sensors one process serves (each has its own services; see docs/architecture.md).
pub const MAX_SENSORS: usize = 4096;

/// Parses a sensor list (`a,b,c`): every entry a valid sensor id, none empty, none twice. The
/// one-line error names `flag`, the entry and its position.
pub fn sensor_list(flag: &str, text: &str) -> Result<Vec<String>, String> {
    let mut out: Vec<String> = Vec::new();
    for (i, raw) in text.split(',').enumerate() {
        let name = raw.trim();
        let at = i + 1;
        if name.is_empty() {
            return Err(format!("{flag} {text:?}: entry {at} is empty"));
        }
        taxel_msgs::sensor_id_bytes(name).map_err(|e| format!("{flag}: entry {at}: {e}"))?;
        if let Some(first) = out.iter().position(|n| n == name) {
            return Err(format!(
                "{flag}: sensor {name:?} is listed twice (entries {} and {at})",
                first + 1
            ));
        }
        out.push(name.to_string());
    }
    if out.len() > MAX_SENSORS {
        return Err(format!(
            "{flag}: {} sensors, at most {MAX_SENSORS} per process",
            out.len()
        ));
    }
    Ok(out)
}

/// `--wake-group NAME` of a process in a shared layout (one process per role for many sensors).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct WakeGroupArg {
    /// Wake-up group of a shared layout (`taxel-group/NAME/<stream>`): a process serving many
    /// sensors (publisher, calibrator) notifies it every few samples of a burst, and one
    /// downstream serving the same sensors (estimator, calibrator, a latency probe of them all)
    /// waits on it and polls their streams instead of listening to each sensor (`taxel up`
    /// sets it for `layout = "shared"`). Every sensor's own notification is still sent.
    #[arg(long, value_name = "NAME")]
    pub wake_group: Option<String>,
}

impl WakeGroupArg {
    /// The group, checked (a one-line error naming the flag otherwise).
    pub fn checked(&self) -> Result<Option<&str>, String> {
        match &self.wake_group {
            None => Ok(None),
            Some(g) => crate::ipc::group_service_name(g, taxel_msgs::Stream::Raw)
                .map(|_| Some(g.as_str()))
                .map_err(|e| format!("--wake-group: {e}")),
        }
    }
}

/// The name of a process serving `sensors` (its iceoryx2 node): `role-a` for one sensor, as
/// before, `role-a+N` for `a` and N more (`+` cannot occur in a sensor id).
pub fn process_name(role: &str, sensors: &[String]) -> String {
    match sensors {
        [] => role.to_string(),
        [one] => format!("{role}-{one}"),
        [first, rest @ ..] => format!("{role}-{first}+{}", rest.len()),
    }
}

/// An option given per sensor: one value for every sensor, or a comma-separated list with one
/// entry per sensor, in the order of `--sensor`. An empty entry (`1,,3`) means "not given" for
/// that sensor where the option allows it.
#[derive(Debug, Clone, PartialEq)]
pub struct PerSensor<T>(pub Vec<Option<T>>);

impl<T: FromStr> FromStr for PerSensor<T>
where
    T::Err: Display,
{
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let mut out = Vec::new();
        for (i, e) in s.split(',').enumerate() {
            let e = e.trim();
            if e.is_empty() {
                out.push(None);
            } else {
                let v = e
                    .parse::<T>()
                    .map_err(|err| format!("entry {} {e:?}: {err}", i + 1))?;
                out.push(Some(v));
            }
        }
        Ok(PerSensor(out))
    }
}

impl<T: Clone> PerSensor<T> {
    /// One value for every sensor.
    pub fn one(v: T) -> PerSensor<T> {
        PerSensor(vec![Some(v)])
    }

    /// Whether one value was given for every sensor (rather than a list).
    pub fn is_single(&self) -> bool {
        self.0.len() == 1
    }

    /// The value of each of `n` sensors (None: not given for that sensor). One entry applies
    /// to all; otherwise there must be exactly `n`.
    pub fn resolve(&self, flag: &str, n: usize) -> Result<Vec<Option<T>>, String> {
        match self.0.len() {
            1 => Ok(vec![self.0[0].clone(); n]),
            k if k == n => Ok(self.0.clone()),
            k => Err(format!(
                "{flag}: {k} values for {n} sensor(s): give one for every sensor or one per sensor"
            )),
        }
    }

    /// Like [`PerSensor::resolve`], for options without "not given": every entry must have a
    /// value.
    pub fn resolve_all(&self, flag: &str, n: usize) -> Result<Vec<T>, String> {
        let v = self.resolve(flag, n)?;
        match v.iter().position(Option::is_none) {
            Some(i) => Err(format!("{flag}: entry {} is empty", i + 1)),
            None => Ok(v.into_iter().flatten().collect()),
        }
    }
}

/// [`PerSensor::resolve`] of an option that may be absent: None for every sensor.
pub fn resolve_opt<T: Clone>(
    v: &Option<PerSensor<T>>,
    flag: &str,
    n: usize,
) -> Result<Vec<Option<T>>, String> {
    match v {
        Some(p) => p.resolve(flag, n),
        None => Ok(vec![None; n]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_lists_are_checked_entry_by_entry() {
        assert_eq!(
            sensor_list("--sensor", "a,b, c").expect("ok"),
            ["a", "b", "c"]
        );
        assert_eq!(sensor_list("--sensor", "s0").expect("ok"), ["s0"]);
        let e = sensor_list("--sensor", "a,,b").expect_err("empty");
        assert!(e.contains("entry 2 is empty"), "{e}");
        let e = sensor_list("--sensor", "a,b,a").expect_err("twice");
        assert!(e.contains("\"a\" is listed twice (entries 1 and 3)"), "{e}");
        let e = sensor_list("--sensor", "a,b c").expect_err("bad id");
        assert!(e.contains("entry 2") && e.contains("\"b c\""), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn per_sensor_values_are_one_for_all_or_one_each() {
        let one: PerSensor<u64> = "5".parse().expect("one");
        assert!(one.is_single());
        assert_eq!(one.resolve_all("--seed", 3).expect("all"), [5, 5, 5]);
        let each: PerSensor<u64> = "1,,3".parse().expect("list");
        assert_eq!(
            each.resolve("--seed", 3).expect("each"),
            [Some(1), None, Some(3)]
        );
        let e = each.resolve_all("--seed", 3).expect_err("empty");
        assert!(e.contains("entry 2 is empty"), "{e}");
        let e = each.resolve("--seed", 2).expect_err("count");
        assert!(e.contains("3 values for 2 sensor(s)"), "{e}");
        let e = "1,x".parse::<PerSensor<u64>>().expect_err("parse");
        assert!(e.starts_with("entry 2 \"x\""), "{e}");
        assert_eq!(
            resolve_opt::<u64>(&None, "--seed", 2).expect("none"),
            [None, None]
        );
    }

    #[test]
    fn process_names_keep_the_single_sensor_form() {
        let v = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert_eq!(process_name("calibrator", &v(&["s0"])), "calibrator-s0");
        assert_eq!(
            process_name("calibrator", &v(&["a", "b", "c"])),
            "calibrator-a+2"
        );
    }
}
