//! Grasp traces: the CSV that `pts sim --csv` writes and `pts estimate --trace` reads, and the
//! conversion of a decoded defmt log into it (`pts trace --from-defmt`).
//!
//! Columns (header required, order free, unknown columns ignored):
//!
//! | column | unit | required |
//! |---|---|---|
//! | `t_s` | s | yes |
//! | `theta_a_rad` | rad, absolute model angle (−0.8503608 at rest) | yes |
//! | `torque_nm` | N·m at the actuator | yes, or `current_a` |
//! | `current_a` | A, motor current (→ T_a with the finger's drive constants) | instead of `torque_nm` |
//! | `encoder_count`, `current_code` | raw u16 readings | optional: exact replay |
//! | `torque_ref_nm`, `duty`, `state` | controller | optional |
//! | `true_theta_a_rad`, `true_torque_nm`, `true_contact`, `true_k_m` | simulation truth | optional |
//!
//! The plant's own trace (`plant::trace`: `theta_a_meas_rad`, `torque_meas_nm`, `adc_code`, …)
//! is read too: its measured columns stand for `theta_a_rad`, `torque_nm`, `current_code`.

use grasp::{Located, Quality, State};
use std::fmt::Write as _;

/// One sample of a grasp.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TraceRow {
    /// Time (s).
    pub t_s: f64,
    /// θa (rad), absolute model angle.
    pub theta_a_rad: f64,
    /// Measured T_a (N·m).
    pub torque_nm: f64,
    /// Torque reference (N·m).
    pub torque_ref_nm: Option<f64>,
    /// Duty (−1..1).
    pub duty: Option<f64>,
    /// Controller state (snake_case).
    pub state: Option<String>,
    /// Raw encoder count (×4, wrapping).
    pub encoder_count: Option<u16>,
    /// Raw ADC code.
    pub current_code: Option<u16>,
    /// Simulation truth: θa (rad).
    pub true_theta_a_rad: Option<f64>,
    /// Simulation truth: T_a (N·m).
    pub true_torque_nm: Option<f64>,
    /// Simulation truth: contact state.
    pub true_contact: Option<String>,
    /// Simulation truth: contact location (m).
    pub true_k_m: Option<f64>,
}

/// snake_case name of a controller state (`fault:<kind>` for faults).
pub fn state_name(s: State) -> String {
    match s {
        State::Init => "init".into(),
        State::Calibrating => "calibrating".into(),
        State::Approach => "approach".into(),
        State::Step => "step".into(),
        State::Settling => "settling".into(),
        State::Estimating => "estimating".into(),
        State::Holding => "holding".into(),
        State::Releasing => "releasing".into(),
        State::Done => "done".into(),
        State::Fault(r) => format!("fault:{}", r.kind()),
        // States added to the controller later: their Debug name in snake_case.
        #[allow(unreachable_patterns)]
        other => snake(&format!("{other:?}")),
    }
}

/// `SomeName { .. }` → `some_name`.
pub fn snake(debug: &str) -> String {
    let head = debug.split([' ', '{', '(']).next().unwrap_or(debug);
    let mut out = String::new();
    for (i, ch) in head.chars().enumerate() {
        if ch.is_uppercase() {
            if i > 0 {
                out.push('_');
            }
            out.extend(ch.to_lowercase());
        } else {
            out.push(ch);
        }
    }
    out
}

/// snake_case name of a location class.
pub fn located_name(l: Located) -> &'static str {
    match l {
        Located::Proximal => "proximal",
        Located::Distal => "distal",
        Located::ProximalOrNearO2 => "proximal_or_near_o2",
    }
}

/// snake_case name of an estimate quality.
pub fn quality_name(q: Quality) -> &'static str {
    match q {
        Quality::Good => "good",
        Quality::LowSignal => "low_signal",
        Quality::Ambiguous => "ambiguous",
    }
}

const COLUMNS: [&str; 12] = [
    "t_s",
    "theta_a_rad",
    "torque_nm",
    "torque_ref_nm",
    "duty",
    "state",
    "encoder_count",
    "current_code",
    "true_theta_a_rad",
    "true_torque_nm",
    "true_contact",
    "true_k_m",
];

/// Writes rows as CSV (every column; empty cells for missing values).
pub fn write_csv(rows: &[TraceRow], out: &mut impl std::io::Write) -> std::io::Result<()> {
    let mut s = String::with_capacity(128 * (rows.len() + 1));
    s.push_str(&COLUMNS.join(","));
    s.push('\n');
    fn opt<T: std::fmt::Display>(s: &mut String, v: &Option<T>) {
        s.push(',');
        if let Some(v) = v {
            let _ = write!(s, "{v}");
        }
    }
    for r in rows {
        let _ = write!(s, "{},{},{}", r.t_s, r.theta_a_rad, r.torque_nm);
        opt(&mut s, &r.torque_ref_nm);
        opt(&mut s, &r.duty);
        opt(&mut s, &r.state);
        opt(&mut s, &r.encoder_count);
        opt(&mut s, &r.current_code);
        opt(&mut s, &r.true_theta_a_rad);
        opt(&mut s, &r.true_torque_nm);
        opt(&mut s, &r.true_contact);
        opt(&mut s, &r.true_k_m);
        s.push('\n');
        if s.len() > 1 << 20 {
            out.write_all(s.as_bytes())?;
            s.clear();
        }
    }
    out.write_all(s.as_bytes())
}

/// A parsed trace with what was skipped on the way.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// Valid rows, in time order.
    pub rows: Vec<TraceRow>,
    /// Human-readable notes about skipped or reordered lines.
    pub warnings: Vec<String>,
}

/// Reads a trace CSV. `current_to_torque` converts a `current_a` column (A → N·m) when there is
/// no `torque_nm`. Errors only when nothing usable is left; skipped lines become warnings.
pub fn read_csv(text: &str, current_to_torque: &dyn Fn(f64) -> f64) -> Result<Trace, String> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((_, header)) = lines.next() else {
        return Err("the trace is empty (no header line)".into());
    };
    let header = header.trim_start_matches('\u{feff}');
    // The plant's own trace (`plant::trace`) names the measured columns differently.
    let names: Vec<String> = header
        .split(',')
        .map(|h| match h.trim() {
            "theta_a_meas_rad" => "theta_a_rad".to_string(),
            "torque_meas_nm" => "torque_nm".to_string(),
            "adc_code" => "current_code".to_string(),
            "theta_a_true_rad" => "true_theta_a_rad".to_string(),
            "torque_true_nm" => "true_torque_nm".to_string(),
            other => other.to_string(),
        })
        .collect();
    let col = |name: &str| names.iter().position(|n| n == name);
    let (Some(it), Some(ith)) = (col("t_s"), col("theta_a_rad")) else {
        return Err(format!(
            "the header must name at least t_s, theta_a_rad and torque_nm (or current_a); it has: {}",
            names.join(",")
        ));
    };
    let torque_col = match (col("torque_nm"), col("current_a")) {
        (Some(i), _) => (i, false),
        (None, Some(i)) => (i, true),
        (None, None) => {
            return Err(format!(
                "the header has neither torque_nm nor current_a; it has: {}",
                names.join(",")
            ))
        }
    };
    let opt_f = |cells: &[&str], name: &str| -> Option<f64> {
        col(name)
            .and_then(|i| cells.get(i))
            .and_then(|c| c.trim().parse::<f64>().ok())
            .filter(|v| v.is_finite())
    };
    let opt_u16 = |cells: &[&str], name: &str| -> Option<u16> {
        col(name)
            .and_then(|i| cells.get(i))
            .and_then(|c| c.trim().parse::<u16>().ok())
    };
    let opt_s = |cells: &[&str], name: &str| -> Option<String> {
        col(name)
            .and_then(|i| cells.get(i))
            .map(|c| c.trim().to_string())
            .filter(|c| !c.is_empty())
    };
    // As many rows as lines (a cheap count): the vector is not grown geometrically (up to
    // twice the rows' size).
    let mut trace = Trace {
        rows: Vec::with_capacity(text.lines().count()),
        warnings: Vec::new(),
    };
    let mut skipped: Vec<usize> = vec![];
    let mut first_reason: Option<String> = None;
    for (line_no, line) in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let num = |i: usize, name: &str| -> Result<f64, String> {
            let cell = cells
                .get(i)
                .ok_or_else(|| format!("line {line_no}: too few fields (no {name})"))?
                .trim();
            match cell.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(format!(
                    "line {line_no}: {name} = \"{cell}\" is not a finite number"
                )),
            }
        };
        let parsed = (|| -> Result<TraceRow, String> {
            let t_s = num(it, "t_s")?;
            let theta_a_rad = num(ith, "theta_a_rad")?;
            let torque_nm = if torque_col.1 {
                current_to_torque(num(torque_col.0, "current_a")?)
            } else {
                num(torque_col.0, "torque_nm")?
            };
            Ok(TraceRow {
                t_s,
                theta_a_rad,
                torque_nm,
                torque_ref_nm: opt_f(&cells, "torque_ref_nm"),
                duty: opt_f(&cells, "duty"),
                state: opt_s(&cells, "state"),
                encoder_count: opt_u16(&cells, "encoder_count"),
                current_code: opt_u16(&cells, "current_code"),
                true_theta_a_rad: opt_f(&cells, "true_theta_a_rad"),
                true_torque_nm: opt_f(&cells, "true_torque_nm"),
                true_contact: opt_s(&cells, "true_contact"),
                true_k_m: opt_f(&cells, "true_k_m"),
            })
        })();
        match parsed {
            Ok(r) => trace.rows.push(r),
            Err(why) => {
                skipped.push(line_no);
                first_reason.get_or_insert(why);
            }
        }
    }
    if let Some(why) = first_reason {
        trace.warnings.push(format!(
            "skipped {} unusable line(s), first: {why}",
            skipped.len()
        ));
    }
    if trace.rows.is_empty() {
        return Err(match trace.warnings.first() {
            Some(w) => format!("no usable rows in the trace ({w})"),
            None => "the trace has a header but no rows".into(),
        });
    }
    if trace.rows.windows(2).any(|w| w[1].t_s < w[0].t_s) {
        trace.rows.sort_by(|a, b| {
            a.t_s
                .partial_cmp(&b.t_s)
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        trace
            .warnings
            .push("rows were not in time order: sorted by t_s".into());
    }
    Ok(trace)
}

/// Control period of the firmware when its log does not say (s): 10 kHz.
pub const FIRMWARE_DT_S: f64 = 1e-4;

/// Converts a decoded defmt log of the firmware (text lines, `src/telemetry.rs`) into trace rows.
///
/// Sample lines carry the marker word `S` and `key=value` pairs (the firmware's is
/// `proto::log::SAMPLE`):
/// `S tick=1200 theta_a_urad=-850361 torque_unm=1234 ref_unm=1300 duty=120 state=Approach`
/// (any prefix, such as defmt's timestamp and level, is ignored). Time is `tick` × the control
/// period, read from the `BOOT … dt_us=100` line, else `dt_s`, else [`FIRMWARE_DT_S`]; a
/// `t_us=`/`t_s=` key is used instead when present. Torque may also come as `current_ua=` or
/// `current_a=` (converted with `current_to_torque`). Other lines (`E`, `P`, `TRUTH`, `END`) are
/// ignored.
pub fn from_defmt(text: &str, dt_s: Option<f64>, current_to_torque: &dyn Fn(f64) -> f64) -> Trace {
    let mut trace = Trace::default();
    let boot_dt = text.lines().find_map(|l| {
        let words: Vec<&str> = l.split_whitespace().collect();
        if !words.contains(&"BOOT") {
            return None;
        }
        words
            .iter()
            .find_map(|w| w.strip_prefix("dt_us="))
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|v| *v > 0.0)
            .map(|v| v / 1e6)
    });
    let dt = dt_s.or(boot_dt).unwrap_or(FIRMWARE_DT_S);
    let mut bad = 0usize;
    for line in text.lines() {
        let mut words = line.split_whitespace();
        if !words.any(|w| w == "S" || w == "tel") {
            continue;
        }
        let mut kv = std::collections::HashMap::new();
        for w in words {
            if let Some((k, v)) = w.split_once('=') {
                kv.insert(k.trim_matches(','), v.trim_matches(','));
            }
        }
        let f = |k: &str| {
            kv.get(k)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
        };
        let t = f("t_s")
            .or_else(|| f("t_us").map(|v| v / 1e6))
            .or_else(|| f("tick").map(|v| v * dt));
        let th = f("theta_a_rad")
            .or_else(|| f("theta_a_urad").map(|v| v / 1e6))
            .or_else(|| f("theta_urad").map(|v| v / 1e6));
        let tq = f("torque_nm")
            .or_else(|| f("torque_unm").map(|v| v / 1e6))
            .or_else(|| f("current_a").map(current_to_torque))
            .or_else(|| f("current_ua").map(|v| current_to_torque(v / 1e6)));
        match (t, th, tq) {
            (Some(t_s), Some(theta_a_rad), Some(torque_nm)) => trace.rows.push(TraceRow {
                t_s,
                theta_a_rad,
                torque_nm,
                torque_ref_nm: f("ref_unm").map(|v| v / 1e6),
                duty: f("duty").map(|v| v / f64::from(grasp::DUTY_MAX)),
                state: kv.get("state").map(|s| snake(s)),
                encoder_count: kv.get("enc").and_then(|v| v.parse().ok()),
                current_code: kv.get("adc").and_then(|v| v.parse().ok()),
                ..TraceRow::default()
            }),
            _ => bad += 1,
        }
    }
    if bad > 0 {
        trace.warnings.push(format!(
            "{bad} sample line(s) lacked a time, θa or torque and were skipped"
        ));
    }
    trace
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nm(i: f64) -> f64 {
        i * 2.0
    }

    #[test]
    fn round_trip() {
        let rows = vec![
            TraceRow {
                t_s: 0.0,
                theta_a_rad: -0.85,
                torque_nm: 0.0,
                state: Some("approach".into()),
                encoder_count: Some(65535),
                ..Default::default()
            },
            TraceRow {
                t_s: 1e-4,
                theta_a_rad: -0.849,
                torque_nm: 0.01,
                true_k_m: Some(0.03),
                ..Default::default()
            },
        ];
        let mut buf = vec![];
        write_csv(&rows, &mut buf).unwrap();
        let t = read_csv(std::str::from_utf8(&buf).unwrap(), &nm).unwrap();
        assert_eq!(t.rows, rows);
        assert!(t.warnings.is_empty());
    }

    #[test]
    fn current_column_is_converted() {
        let t = read_csv("t_s,current_a,theta_a_rad\n0,0.5,-0.8\n", &nm).unwrap();
        assert_eq!(t.rows[0].torque_nm, 1.0);
    }

    #[test]
    fn bad_inputs_give_messages_not_panics() {
        assert!(read_csv("", &nm).unwrap_err().contains("empty"));
        assert!(read_csv("a,b\n1,2\n", &nm).unwrap_err().contains("t_s"));
        assert!(read_csv("t_s,theta_a_rad\n1,2\n", &nm)
            .unwrap_err()
            .contains("torque_nm"));
        assert!(read_csv("t_s,theta_a_rad,torque_nm\n", &nm)
            .unwrap_err()
            .contains("no rows"));
        let e = read_csv("t_s,theta_a_rad,torque_nm\nx,1,2\n", &nm).unwrap_err();
        assert!(e.contains("line 2") && e.contains("t_s"), "{e}");
        let t = read_csv("t_s,theta_a_rad,torque_nm\n1,1,1\n0,1,1\n2,1\n", &nm).unwrap();
        assert_eq!(t.rows.len(), 2);
        assert_eq!(t.rows[0].t_s, 0.0);
        assert_eq!(t.warnings.len(), 2, "{:?}", t.warnings);
    }

    #[test]
    fn the_firmware_sample_line_reads_back_to_its_values() {
        // The line as the firmware writes it (proto::log::SAMPLE, the literal it hands to
        // defmt), behind a decoder's timestamp and level.
        let mut line = String::from("0.004000 INFO  ");
        let args: [&dyn std::fmt::Display; 6] = [
            &40u32,
            &-850_361i32,
            &123_456i32,
            &130_000i32,
            &-2500i16,
            &"Seating",
        ];
        proto::log::render(&mut line, proto::log::SAMPLE, &args).unwrap();
        let t = from_defmt(&line, Some(1e-4), &nm);
        assert_eq!(t.warnings, Vec::<String>::new());
        let r = &t.rows[0];
        assert!((r.t_s - 40.0 * 1e-4).abs() < 1e-15);
        assert!((r.theta_a_rad - -0.850361).abs() < 1e-15);
        assert!((r.torque_nm - 0.123456).abs() < 1e-15);
        assert_eq!(r.torque_ref_nm, Some(0.13));
        assert_eq!(r.duty, Some(-0.25));
        assert_eq!(r.state.as_deref(), Some("seating"));
    }

    #[test]
    fn defmt_lines() {
        // The firmware's lines (src/telemetry.rs), as a defmt decoder prints them.
        let log = "0 INFO  BOOT finger=paper l2_um=75000 scene=table2 board=qemu dt_us=200\n\
                   200 INFO  S tick=200 theta_a_urad=-850360 torque_unm=1000 ref_unm=900 duty=-5000 state=Approach\n\
                   300 INFO  P first_contact t_us=300 theta_a_urad=-1 torque_unm=2 phalanx=distal k_um=3\n\
                   400 INFO  S tick=400 theta_a_urad=oops torque_unm=1000\n\
                   500 INFO  S tick=500 theta_a_urad=-800000 torque_unm=1 ref_unm=2 duty=1 state=Fault(NoContact)\n";
        let t = from_defmt(log, None, &nm);
        assert_eq!(t.rows.len(), 2, "{:?}", t.rows);
        assert!((t.rows[0].t_s - 0.04).abs() < 1e-15);
        assert!((t.rows[0].theta_a_rad - -0.85036).abs() < 1e-15);
        assert_eq!(t.rows[0].duty, Some(-0.5));
        assert_eq!(t.rows[0].state.as_deref(), Some("approach"));
        assert_eq!(t.rows[1].state.as_deref(), Some("fault"));
        assert_eq!(t.warnings.len(), 1);
        // An explicit period wins over the BOOT line.
        let t = from_defmt(log, Some(1e-3), &nm);
        assert!((t.rows[0].t_s - 0.2).abs() < 1e-12);
    }
}
