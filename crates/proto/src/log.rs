//! The firmware's log lines, defined once: the text the firmware hands to defmt (over RTT or
//! semihosting), the host runner (`finger-fw simulate`) prints, and xtask and `pts trace` read
//! back. Each line is a marker word and `key=value` pairs; an event line is `E` and the
//! event's `Debug`/`defmt::Format` text.
//!
//! The format of each line is one literal in `log_line!`, which passes it to a logging
//! macro (defmt needs a literal) and gives the consts ([`SAMPLE`], [`PLANT`], [`TRUTH`],
//! [`EVENT`]) that [`render`] fills on the host. The parsers ([`int`], [`word`],
//! [`SampleLine::parse`], [`event_name`]) read the same keys.

use core::fmt::{self, Display, Write};

/// Calls the logging macro named second with the format literal of the line named first,
/// then the arguments: `proto::log_line!(sample, defmt::info, tick, theta, ...)`.
///
/// Lines: `sample` (decimated controller sample), `event` (a controller event), `plant` (a
/// simulated-finger event), `truth` (the simulated finger's truth). Placeholders are defmt's
/// (`{=u32}`, `{}`); [`render`] fills any `{…}` with the next argument.
#[macro_export]
macro_rules! log_line {
    (sample, $($m:ident)::+, $($args:tt)*) => {
        $($m)::+!(
            "S tick={=u32} theta_a_urad={=i32} torque_unm={=i32} ref_unm={=i32} duty={=i16} state={}",
            $($args)*
        )
    };
    (event, $($m:ident)::+, $($args:tt)*) => {
        $($m)::+!("E {}", $($args)*)
    };
    (plant, $($m:ident)::+, $($args:tt)*) => {
        $($m)::+!(
            "P {=str} t_us={=u32} theta_a_urad={=i32} torque_unm={=i32} phalanx={=str} k_um={=i32}",
            $($args)*
        )
    };
    (truth, $($m:ident)::+, $($args:tt)*) => {
        $($m)::+!(
            "TRUTH at={=str} t_us={=u32} theta_a_urad={=i32} torque_unm={=i32} contact={=str} k_um={=i32}",
            $($args)*
        )
    };
}

/// The format literal itself (for the consts below).
macro_rules! literal {
    ($s:literal, $($rest:tt)*) => {
        $s
    };
}

/// Format of the sample line: tick, θa (µrad), measured T_a (µN·m), torque reference
/// (µN·m), duty (±10 000), state.
pub const SAMPLE: &str = log_line!(sample, literal,);
/// Format of a controller event line: the event's `Debug` text.
pub const EVENT: &str = log_line!(event, literal,);
/// Format of a plant event line: kind, simulated time (µs), θa (µrad), T_a (µN·m), phalanx
/// (empty when the event has none), contact location (µm).
pub const PLANT: &str = log_line!(plant, literal,);
/// Format of the truth line: where it was taken, simulated time (µs), true θa (µrad), true
/// T_a (µN·m), contact state, contact location (µm).
pub const TRUTH: &str = log_line!(truth, literal,);

/// Writes `fmt` with each `{…}` placeholder replaced by the next of `args` (`Display`), as a
/// defmt decoder prints the line; placeholders beyond `args` are written empty.
pub fn render(out: &mut impl Write, fmt: &str, args: &[&dyn Display]) -> fmt::Result {
    let mut args = args.iter();
    let mut rest = fmt;
    while let Some(open) = rest.find('{') {
        out.write_str(&rest[..open])?;
        let after = &rest[open..];
        let close = after.find('}').unwrap_or(after.len().saturating_sub(1));
        if let Some(a) = args.next() {
            write!(out, "{a}")?;
        }
        rest = after.get(close + 1..).unwrap_or("");
    }
    out.write_str(rest)
}

/// Where `key` followed by `sep` starts a field in `msg` (not inside a longer name), from `from`.
fn field_at(msg: &str, key: &str, sep: &str, mut from: usize) -> Option<usize> {
    let bytes = msg.as_bytes();
    while let Some(pos) = msg.get(from..)?.find(key) {
        let at = from + pos;
        let end = at + key.len();
        let before_ok = at == 0 || {
            let b = bytes[at - 1];
            !b.is_ascii_alphanumeric() && b != b'_'
        };
        if before_ok && msg.get(end..).is_some_and(|r| r.starts_with(sep)) {
            return Some(end + sep.len());
        }
        from = end;
    }
    None
}

/// The integer value of `key=N` (a line's field) or `key: N` (an event's field, also
/// `key: Some(N)`) in `msg`; `None` when absent or not a number.
pub fn int(msg: &str, key: &str) -> Option<i64> {
    for sep in ["=", ": "] {
        let mut from = 0;
        while let Some(start) = field_at(msg, key, sep, from) {
            let rest = &msg[start..];
            let rest = rest.strip_prefix("Some(").unwrap_or(rest);
            let len = rest
                .find(|c: char| !(c.is_ascii_digit() || c == '-'))
                .unwrap_or(rest.len());
            if let Ok(v) = rest[..len].parse() {
                return Some(v);
            }
            from = start;
        }
    }
    None
}

/// The word after `key=` (up to a space).
pub fn word<'a>(msg: &'a str, key: &str) -> Option<&'a str> {
    let start = field_at(msg, key, "=", 0)?;
    let rest = &msg[start..];
    Some(rest.split(' ').next().unwrap_or(rest))
}

/// The name of the event on an event line (`E Name { .. }` → `Name`).
pub fn event_name(msg: &str) -> Option<&str> {
    let e = msg.strip_prefix("E ")?;
    let len = e
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(e.len());
    Some(&e[..len])
}

/// One sample line, read back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleLine<'a> {
    /// Control tick.
    pub tick: u32,
    /// θa (µrad).
    pub theta_a_urad: i32,
    /// Measured T_a (µN·m).
    pub torque_unm: i32,
    /// Torque reference (µN·m).
    pub ref_unm: i32,
    /// Duty (±10 000).
    pub duty: i16,
    /// The state's `Debug` text (`Approach`, `Fault(NoContact)`).
    pub state: &'a str,
}

impl<'a> SampleLine<'a> {
    /// Reads a sample line (the message, starting with its marker `S`); `None` for any
    /// other line or a missing or malformed field.
    pub fn parse(msg: &'a str) -> Option<Self> {
        msg.strip_prefix("S ")?;
        let num = |k: &str| int(msg, k);
        Some(Self {
            tick: u32::try_from(num("tick")?).ok()?,
            theta_a_urad: i32::try_from(num("theta_a_urad")?).ok()?,
            torque_unm: i32::try_from(num("torque_unm")?).ok()?,
            ref_unm: i32::try_from(num("ref_unm")?).ok()?,
            duty: i16::try_from(num("duty")?).ok()?,
            state: word(msg, "state")?,
        })
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::string::String;

    fn line(fmt: &str, args: &[&dyn Display]) -> String {
        let mut s = String::new();
        render(&mut s, fmt, args).unwrap();
        s
    }

    #[test]
    fn a_sample_line_as_the_firmware_writes_it_parses_to_its_values() {
        // The firmware passes SAMPLE's literal to defmt::info! with these arguments; the
        // decoder prints each `{=T}` / `{}` as the value's text.
        let s = line(
            SAMPLE,
            &[
                &70_119u32,
                &-141_570i32,
                &1_228_600i32,
                &1_229_500i32,
                &-1234i16,
                &"Fault(NoContact)",
            ],
        );
        assert_eq!(
            s,
            "S tick=70119 theta_a_urad=-141570 torque_unm=1228600 ref_unm=1229500 duty=-1234 state=Fault(NoContact)"
        );
        assert_eq!(
            SampleLine::parse(&s),
            Some(SampleLine {
                tick: 70_119,
                theta_a_urad: -141_570,
                torque_unm: 1_228_600,
                ref_unm: 1_229_500,
                duty: -1234,
                state: "Fault(NoContact)",
            })
        );
        // Extremes survive the round trip.
        let s = line(
            SAMPLE,
            &[&u32::MAX, &i32::MIN, &i32::MAX, &0i32, &i16::MIN, &"Init"],
        );
        let p = SampleLine::parse(&s).unwrap();
        assert_eq!(
            (p.tick, p.theta_a_urad, p.torque_unm, p.duty),
            (u32::MAX, i32::MIN, i32::MAX, i16::MIN)
        );
    }

    #[test]
    fn plant_truth_and_event_lines_read_back() {
        let p = line(
            PLANT,
            &[
                &"first_contact",
                &4_460_400u32,
                &-223_770i32,
                &340_800i32,
                &"distal",
                &29_270i32,
            ],
        );
        assert!(p.starts_with("P first_contact "));
        assert_eq!(int(&p, "t_us"), Some(4_460_400));
        assert_eq!(int(&p, "theta_a_urad"), Some(-223_770));
        assert_eq!(int(&p, "torque_unm"), Some(340_800));
        assert_eq!(word(&p, "phalanx"), Some("distal"));
        assert_eq!(int(&p, "k_um"), Some(29_270));
        let t = line(
            TRUTH,
            &[
                &"settled",
                &6_811_900u32,
                &-141_600i32,
                &1_228_000i32,
                &"distal",
                &39_480i32,
            ],
        );
        assert_eq!(word(&t, "at"), Some("settled"));
        assert_eq!(word(&t, "contact"), Some("distal"));
        assert_eq!(int(&t, "k_um"), Some(39_480));
        let e = line(EVENT, &[&"Estimated { tick: 53244, result: EstimateResult { k2_um: Some(50250), kc_hat_unm_per_rad: 13301498 } }"]);
        assert_eq!(event_name(&e), Some("Estimated"));
        assert_eq!(int(&e, "k2_um"), Some(50_250));
        assert_eq!(int(&e, "tick"), Some(53_244));
    }

    #[test]
    fn fields_match_whole_names_only() {
        let m = "E Estimated { tick: 1, result: R { k2_um: Some(50250) } }";
        assert_eq!(int(m, "um"), None);
        assert_eq!(int(m, "k2_um"), Some(50_250));
        assert_eq!(int("k2_um: None", "k2_um"), None);
        let s = "END status=2 state=Fault(Stall) ticks=14001 work_max=-3 max=7";
        assert_eq!(int(s, "max"), Some(7));
        assert_eq!(int(s, "work_max"), Some(-3));
        assert_eq!(word(s, "state"), Some("Fault(Stall)"));
        assert_eq!(int(s, "missing"), None);
        assert_eq!(SampleLine::parse("S tick=1 theta_a_urad=x"), None);
        assert_eq!(SampleLine::parse(s), None);
        assert_eq!(event_name("S tick=1"), None);
    }
}
