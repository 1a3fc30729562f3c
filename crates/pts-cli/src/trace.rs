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
//! `t_ms`/`t_us` stand for `t_s` and `theta_a_deg` for `theta_a_rad`; fields may be quoted and
//! separated by `,`, `;` or tab ([`read_csv`]).

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

/// A parsed trace with what was skipped on the way, held by column: the three required columns
/// as `f64`, and only the optional columns the file has (an `f64` column holds NaN where a row
/// has no value: the values read are finite; the text columns are numbers into a table of the
/// distinct strings). A narrow three-column recording then holds 24 B a row against its 29 B
/// of text, not a full [`TraceRow`] (160 B) per row; [`Trace::row`] gives one when wanted.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    /// Time (s) of each valid row, in time order.
    pub t_s: Vec<f64>,
    /// θa (rad), absolute model angle, per row.
    pub theta_a_rad: Vec<f64>,
    /// Measured T_a (N·m) per row.
    pub torque_nm: Vec<f64>,
    /// The optional columns present.
    opt: OptColumns,
    /// Human-readable notes about skipped or reordered lines.
    pub warnings: Vec<String>,
}

/// [`Trace`]'s optional columns: `None` when the trace has no such column.
#[derive(Clone, Debug, Default, PartialEq)]
struct OptColumns {
    torque_ref_nm: Option<Vec<f64>>,
    duty: Option<Vec<f64>>,
    state: Option<Vec<u32>>,
    encoder_count: Option<Vec<Option<u16>>>,
    current_code: Option<Vec<Option<u16>>>,
    true_theta_a_rad: Option<Vec<f64>>,
    true_torque_nm: Option<Vec<f64>>,
    true_contact: Option<Vec<u32>>,
    true_k_m: Option<Vec<f64>>,
    /// The distinct strings of the text columns; [`NO_STR`] for an empty cell.
    strings: Vec<String>,
}

/// A text cell without a value.
const NO_STR: u32 = u32::MAX;

fn opt_f(v: Option<&Vec<f64>>, i: usize) -> Option<f64> {
    v.and_then(|c| c.get(i).copied()).filter(|x| !x.is_nan())
}

fn permute<T: Copy>(v: &mut Vec<T>, order: &[u32]) {
    *v = order.iter().map(|&i| v[i as usize]).collect();
}

impl Trace {
    /// Rows.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Row `i`'s raw encoder count.
    pub fn encoder_count(&self, i: usize) -> Option<u16> {
        self.opt
            .encoder_count
            .as_ref()
            .and_then(|c| c.get(i).copied().flatten())
    }

    /// Row `i`'s raw ADC code.
    pub fn current_code(&self, i: usize) -> Option<u16> {
        self.opt
            .current_code
            .as_ref()
            .and_then(|c| c.get(i).copied().flatten())
    }

    fn text(&self, col: Option<&Vec<u32>>, i: usize) -> Option<String> {
        let id = *col?.get(i)?;
        self.opt.strings.get(id as usize).cloned()
    }

    /// Row `i` with every column (`None` past the end).
    pub fn row(&self, i: usize) -> Option<TraceRow> {
        let o = &self.opt;
        Some(TraceRow {
            t_s: *self.t_s.get(i)?,
            theta_a_rad: *self.theta_a_rad.get(i)?,
            torque_nm: *self.torque_nm.get(i)?,
            torque_ref_nm: opt_f(o.torque_ref_nm.as_ref(), i),
            duty: opt_f(o.duty.as_ref(), i),
            state: self.text(o.state.as_ref(), i),
            encoder_count: self.encoder_count(i),
            current_code: self.current_code(i),
            true_theta_a_rad: opt_f(o.true_theta_a_rad.as_ref(), i),
            true_torque_nm: opt_f(o.true_torque_nm.as_ref(), i),
            true_contact: self.text(o.true_contact.as_ref(), i),
            true_k_m: opt_f(o.true_k_m.as_ref(), i),
        })
    }

    /// Every row, with every column.
    pub fn to_rows(&self) -> Vec<TraceRow> {
        (0..self.len()).filter_map(|i| self.row(i)).collect()
    }

    /// The trace of these rows (an optional column is kept when a row has a value in it).
    pub fn from_rows(rows: &[TraceRow], warnings: Vec<String>) -> Trace {
        let mut b = Builder::new(rows.len(), |name| {
            let any = |f: &dyn Fn(&TraceRow) -> bool| rows.iter().any(f);
            match name {
                "torque_ref_nm" => any(&|r| r.torque_ref_nm.is_some()),
                "duty" => any(&|r| r.duty.is_some()),
                "state" => any(&|r| r.state.is_some()),
                "encoder_count" => any(&|r| r.encoder_count.is_some()),
                "current_code" => any(&|r| r.current_code.is_some()),
                "true_theta_a_rad" => any(&|r| r.true_theta_a_rad.is_some()),
                "true_torque_nm" => any(&|r| r.true_torque_nm.is_some()),
                "true_contact" => any(&|r| r.true_contact.is_some()),
                "true_k_m" => any(&|r| r.true_k_m.is_some()),
                _ => false,
            }
        });
        for r in rows {
            b.push(r.t_s, r.theta_a_rad, r.torque_nm, |name| match name {
                Cell::F(n) => match n {
                    "torque_ref_nm" => r.torque_ref_nm,
                    "duty" => r.duty,
                    "true_theta_a_rad" => r.true_theta_a_rad,
                    "true_torque_nm" => r.true_torque_nm,
                    _ => r.true_k_m,
                }
                .map(CellValue::F),
                Cell::U(n) => match n {
                    "encoder_count" => r.encoder_count,
                    _ => r.current_code,
                }
                .map(CellValue::U),
                Cell::S(n) => match n {
                    "state" => r.state.as_deref(),
                    _ => r.true_contact.as_deref(),
                }
                .map(CellValue::S),
            });
        }
        let mut t = b.finish();
        t.warnings = warnings;
        t
    }

    /// Sorts the rows by time (stable: rows with equal times keep their order).
    fn sort_by_time(&mut self) {
        let mut order: Vec<u32> = (0..self.len() as u32).collect();
        let t = &self.t_s;
        order.sort_by(|&a, &b| {
            t[a as usize]
                .partial_cmp(&t[b as usize])
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        permute(&mut self.t_s, &order);
        permute(&mut self.theta_a_rad, &order);
        permute(&mut self.torque_nm, &order);
        let o = &mut self.opt;
        for c in [
            &mut o.torque_ref_nm,
            &mut o.duty,
            &mut o.true_theta_a_rad,
            &mut o.true_torque_nm,
            &mut o.true_k_m,
        ]
        .into_iter()
        .flatten()
        {
            permute(c, &order);
        }
        for c in [&mut o.state, &mut o.true_contact].into_iter().flatten() {
            permute(c, &order);
        }
        for c in [&mut o.encoder_count, &mut o.current_code]
            .into_iter()
            .flatten()
        {
            permute(c, &order);
        }
    }
}

/// An optional cell asked of a row by its column name.
enum Cell<'a> {
    F(&'a str),
    U(&'a str),
    S(&'a str),
}

enum CellValue<'a> {
    F(f64),
    U(u16),
    S(&'a str),
}

/// Fills a [`Trace`] row by row, with exactly the optional columns asked for at the start.
struct Builder {
    t: Trace,
    ids: std::collections::HashMap<String, u32>,
}

impl Builder {
    /// Room for `rows` rows; `has(column)` tells which optional columns to hold.
    fn new(rows: usize, has: impl Fn(&str) -> bool) -> Builder {
        let f = |n: &str| has(n).then(|| Vec::with_capacity(rows));
        let s = |n: &str| has(n).then(|| Vec::with_capacity(rows));
        let u = |n: &str| has(n).then(|| Vec::with_capacity(rows));
        Builder {
            t: Trace {
                t_s: Vec::with_capacity(rows),
                theta_a_rad: Vec::with_capacity(rows),
                torque_nm: Vec::with_capacity(rows),
                opt: OptColumns {
                    torque_ref_nm: f("torque_ref_nm"),
                    duty: f("duty"),
                    state: s("state"),
                    encoder_count: u("encoder_count"),
                    current_code: u("current_code"),
                    true_theta_a_rad: f("true_theta_a_rad"),
                    true_torque_nm: f("true_torque_nm"),
                    true_contact: s("true_contact"),
                    true_k_m: f("true_k_m"),
                    strings: Vec::new(),
                },
                warnings: Vec::new(),
            },
            ids: std::collections::HashMap::new(),
        }
    }

    /// One row: the required values, and `cell` asked for each optional column held.
    fn push<'a>(
        &mut self,
        t_s: f64,
        theta_a_rad: f64,
        torque_nm: f64,
        mut cell: impl FnMut(Cell<'_>) -> Option<CellValue<'a>>,
    ) {
        let t = &mut self.t;
        t.t_s.push(t_s);
        t.theta_a_rad.push(theta_a_rad);
        t.torque_nm.push(torque_nm);
        let o = &mut t.opt;
        for (name, col) in [
            ("torque_ref_nm", &mut o.torque_ref_nm),
            ("duty", &mut o.duty),
            ("true_theta_a_rad", &mut o.true_theta_a_rad),
            ("true_torque_nm", &mut o.true_torque_nm),
            ("true_k_m", &mut o.true_k_m),
        ] {
            if let Some(c) = col {
                c.push(match cell(Cell::F(name)) {
                    Some(CellValue::F(v)) => v,
                    _ => f64::NAN,
                });
            }
        }
        for (name, col) in [
            ("encoder_count", &mut o.encoder_count),
            ("current_code", &mut o.current_code),
        ] {
            if let Some(c) = col {
                c.push(match cell(Cell::U(name)) {
                    Some(CellValue::U(v)) => Some(v),
                    _ => None,
                });
            }
        }
        for (name, col) in [
            ("state", &mut o.state),
            ("true_contact", &mut o.true_contact),
        ] {
            if let Some(c) = col {
                let id = match cell(Cell::S(name)) {
                    Some(CellValue::S(v)) => match self.ids.get(v) {
                        Some(&id) => id,
                        None => {
                            let id = o.strings.len() as u32;
                            o.strings.push(v.to_string());
                            self.ids.insert(v.to_string(), id);
                            id
                        }
                    },
                    _ => NO_STR,
                };
                c.push(id);
            }
        }
    }

    fn finish(self) -> Trace {
        self.t
    }
}

/// Longest header an error message quotes (characters).
const SHOWN_HEADER_CHARS: usize = 120;

/// A header as an error message quotes it: control characters escaped (a binary file is not
/// printed raw to the terminal), cut at [`SHOWN_HEADER_CHARS`] with an ellipsis.
fn shown_header(names: &[String]) -> String {
    let joined = names.join(",");
    let mut out = String::new();
    for c in joined.chars().take(SHOWN_HEADER_CHARS) {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    if joined.chars().count() > SHOWN_HEADER_CHARS {
        out.push('…');
    }
    out
}

/// The field separator of a trace: whichever of `,`, `;` and tab its header line holds most
/// of (`,` on a tie or none). A spreadsheet set to a decimal comma writes `;`.
fn sniff_delimiter(text: &str) -> u8 {
    let header = text
        .lines()
        .map(|l| l.trim().trim_start_matches('\u{feff}'))
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    let count = |c: char| header.matches(c).count();
    [b';', b'\t']
        .into_iter()
        .map(|d| (count(char::from(d)), d))
        .filter(|(n, _)| *n > count(','))
        .max_by_key(|(n, _)| *n)
        .map_or(b',', |(_, d)| d)
}

/// The header names a trace may give its columns in other units, with how many of that unit
/// make one of the canonical column's: time in ms or µs, θa in degrees. Values are divided by
/// it, so that whole milliseconds read as the same times as their seconds written out.
const SCALED_COLUMNS: [(&str, &str, f64); 3] = [
    ("t_ms", "t_s", 1e3),
    ("t_us", "t_s", 1e6),
    ("theta_a_deg", "theta_a_rad", 180.0 / core::f64::consts::PI),
];

/// Reads a trace CSV. `current_to_torque` converts a `current_a` column (A → N·m) when there is
/// no `torque_nm`. Errors only when nothing usable is left; skipped lines become warnings.
///
/// Fields may be quoted, and separated by `,`, `;` or tab (whichever the header line holds
/// most of); with `;` or tab a decimal comma reads as a decimal point. `t_ms`,
/// `t_us` and `theta_a_deg` stand for `t_s` and `theta_a_rad` in those units.
pub fn read_csv(text: &str, current_to_torque: &dyn Fn(f64) -> f64) -> Result<Trace, String> {
    let delimiter = sniff_delimiter(text);
    let decimal_comma = delimiter != b',';
    let mut reader = csv::ReaderBuilder::new()
        .delimiter(delimiter)
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let mut record = csv::StringRecord::new();
    // The next record with a field in it that is not a comment, with its line number.
    let mut next = |record: &mut csv::StringRecord| -> Option<Result<u64, String>> {
        loop {
            match reader.read_record(record) {
                Ok(false) => return None,
                Ok(true) => {}
                Err(e) => {
                    let line = e.position().map_or(0, csv::Position::line);
                    return Some(Err(format!("line {line}: {e}")));
                }
            }
            // (A byte-order mark before the first record is csv's to strip.)
            let first = record.get(0).unwrap_or("");
            if first.starts_with('#') || record.iter().all(str::is_empty) {
                continue;
            }
            return Some(Ok(record.position().map_or(0, csv::Position::line)));
        }
    };
    let header = match next(&mut record) {
        None => return Err("the trace is empty (no header line)".into()),
        Some(Err(e)) => return Err(format!("the header cannot be read: {e}")),
        Some(Ok(_)) => record.clone(),
    };
    // The plant's own trace (`plant::trace`) names the measured columns differently.
    let names: Vec<String> = header
        .iter()
        .map(|h| match h {
            "theta_a_meas_rad" => "theta_a_rad".to_string(),
            "torque_meas_nm" => "torque_nm".to_string(),
            "adc_code" => "current_code".to_string(),
            "theta_a_true_rad" => "true_theta_a_rad".to_string(),
            "torque_true_nm" => "true_torque_nm".to_string(),
            other => other.to_string(),
        })
        .collect();
    let col = |name: &str| names.iter().position(|n| n == name);
    // A required column, or one of its stand-ins: (index, units per canonical unit, its name).
    let scaled = |name: &'static str| -> Option<(usize, f64, &'static str)> {
        col(name).map(|i| (i, 1.0, name)).or_else(|| {
            SCALED_COLUMNS
                .iter()
                .filter(|(_, canon, _)| *canon == name)
                .find_map(|(alt, _, k)| col(alt).map(|i| (i, *k, *alt)))
        })
    };
    let (Some(it), Some(ith)) = (scaled("t_s"), scaled("theta_a_rad")) else {
        return Err(format!(
            "the header must name at least t_s (or t_ms, t_us), theta_a_rad (or theta_a_deg) \
             and torque_nm (or current_a); it has: {}",
            shown_header(&names)
        ));
    };
    let torque_col = match (col("torque_nm"), col("current_a")) {
        (Some(i), _) => (i, false),
        (None, Some(i)) => (i, true),
        (None, None) => {
            return Err(format!(
                "the header has neither torque_nm nor current_a; it has: {}",
                shown_header(&names)
            ))
        }
    };
    let parse = |cell: &str| -> Option<f64> {
        match cell.parse::<f64>() {
            Ok(v) => Some(v),
            Err(_) if decimal_comma && cell.matches(',').count() == 1 && !cell.contains('.') => {
                cell.replacen(',', ".", 1).parse::<f64>().ok()
            }
            Err(_) => None,
        }
    };
    // As many rows as lines (a cheap count): the columns are not grown geometrically (up to
    // twice their size), and hold only the optional columns the header names.
    let mut b = Builder::new(text.lines().count(), |name| col(name).is_some());
    let mut warnings = Vec::new();
    let mut skipped = 0usize;
    let mut first_reason: Option<String> = None;
    while let Some(line) = next(&mut record) {
        let line_no = match line {
            Ok(n) => n,
            Err(why) => {
                skipped += 1;
                first_reason.get_or_insert(why);
                continue;
            }
        };
        let cells = &record;
        let num = |(i, per_unit, name): (usize, f64, &str)| -> Result<f64, String> {
            let cell = cells
                .get(i)
                .ok_or_else(|| format!("line {line_no}: too few fields (no {name})"))?;
            match parse(cell) {
                Some(v) if v.is_finite() => Ok(v / per_unit),
                _ => Err(format!(
                    "line {line_no}: {name} = \"{cell}\" is not a finite number"
                )),
            }
        };
        let parsed = (|| -> Result<(f64, f64, f64), String> {
            let t_s = num(it)?;
            let theta_a_rad = num(ith)?;
            let torque_nm = if torque_col.1 {
                current_to_torque(num((torque_col.0, 1.0, "current_a"))?)
            } else {
                num((torque_col.0, 1.0, "torque_nm"))?
            };
            Ok((t_s, theta_a_rad, torque_nm))
        })();
        match parsed {
            Ok((t_s, theta_a_rad, torque_nm)) => {
                let cell_of = |name: &str| col(name).and_then(|i| cells.get(i));
                b.push(t_s, theta_a_rad, torque_nm, |c| match c {
                    Cell::F(n) => cell_of(n)
                        .and_then(parse)
                        .filter(|v| v.is_finite())
                        .map(CellValue::F),
                    Cell::U(n) => cell_of(n)
                        .and_then(|c| c.parse::<u16>().ok())
                        .map(CellValue::U),
                    Cell::S(n) => cell_of(n).filter(|c| !c.is_empty()).map(CellValue::S),
                });
            }
            Err(why) => {
                skipped += 1;
                first_reason.get_or_insert(why);
            }
        }
    }
    let mut trace = b.finish();
    if let Some(why) = first_reason {
        warnings.push(format!("skipped {skipped} unusable line(s), first: {why}"));
    }
    trace.warnings = warnings;
    if trace.is_empty() {
        return Err(match trace.warnings.first() {
            Some(w) => format!("no usable rows in the trace ({w})"),
            None => "the trace has a header but no rows".into(),
        });
    }
    if trace.t_s.windows(2).any(|w| w[1] < w[0]) {
        trace.sort_by_time();
        trace
            .warnings
            .push("rows were not in time order: sorted by t_s".into());
    }
    let mut repeats = trace.t_s.windows(2).filter(|w| w[1] == w[0]).map(|w| w[0]);
    if let Some(t) = repeats.next() {
        let repeated = 1 + repeats.count();
        trace.warnings.push(format!(
            "{repeated} row(s) repeat the time of the row before (first at t_s = {t}): both kept"
        ));
    }
    if let Some(note) = trace.snap_jittered_clock() {
        trace.warnings.push(note);
    }
    Ok(trace)
}

/// How far (a fraction of the period) the row times of a regular recording may scatter about
/// their grid and still be read as a jittered clock: beyond it, the rows are left as they are.
pub const CLOCK_JITTER_MAX: f64 = 0.3;

/// θa must be at least this much smoother (in the sum of squared second derivatives) on the
/// grid than at the logged times for the grid's times to replace them.
pub const CLOCK_SMOOTHER: f64 = 0.8;

impl Trace {
    /// Row times logged with a jittered clock read at their regular grid's times. A logger
    /// that stamps rows when they arrive (a host reading a serial port) scatters the times of
    /// rows that were sampled on a regular grid; read as they are, a 4 ms block holds 3 to 5
    /// rows whose mean time moves by up to half a row, and the blocks' θa and torque no longer
    /// lie where the estimator places them. When every row lies within [`CLOCK_JITTER_MAX`]
    /// of a period of a regular grid (rows missing from it are fine) but not on it, and θa is
    /// smoother on the grid than at the logged times (by [`CLOCK_SMOOTHER`]; a recording
    /// sampled at the logged times is smoother at them), the times become the grid's (a
    /// least-squares line through the slot numbers, so a clock running a little fast or slow
    /// is kept). Returns what was done, for the warnings; a regular recording is left bit for
    /// bit as it was.
    fn snap_jittered_clock(&mut self) -> Option<String> {
        let n = self.len();
        if n < 8 {
            return None;
        }
        let t0 = self.t_s[0];
        // The period: the median of up to 1024 steps spread over the rows (no copy of the
        // column: the trace may be long, and a reader holds about twice its file).
        let stride = (n - 1).div_ceil(1024);
        let mut steps: Vec<f64> = (0..n - 1)
            .step_by(stride)
            .map(|i| self.t_s[i + 1] - self.t_s[i])
            .collect();
        let mid = steps.len() / 2;
        let median = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
        // Rows missing from the grid lengthen some steps: the median again without them.
        steps.retain(|d| *d <= 1.5 * median);
        if steps.is_empty() {
            return None;
        }
        let mid = steps.len() / 2;
        let mut period = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
        if !(period.is_finite() && period > 0.0) {
            return None;
        }
        // Slots step by step (each step rounded on its own, so that the period's error does
        // not add up over the rows; two rows in one slot is not a jittered grid), then the
        // least-squares line t − t0 ≈ a + b·slot about the means; twice, the second time
        // with the line's period.
        let nf = n as f64;
        let (mut a, mut b) = (0.0, period);
        for _ in 0..2 {
            period = b;
            let (mut ss, mut st) = (0.0, 0.0);
            for (s, t) in slot_numbers(&self.t_s, period).zip(&self.t_s) {
                ss += s?;
                st += t - t0;
            }
            let (ms, mt) = (ss / nf, st / nf);
            let (mut sst, mut sss) = (0.0, 0.0);
            for (s, t) in slot_numbers(&self.t_s, period).zip(&self.t_s) {
                let ds = s.unwrap_or(0.0) - ms;
                sst += ds * (t - t0 - mt);
                sss += ds * ds;
            }
            b = sst / sss;
            a = mt - b * ms;
            if !(a.is_finite() && b.is_finite() && b > 0.0) {
                return None;
            }
        }
        let grid =
            || slot_numbers(&self.t_s, period).map(move |s| s.map_or(f64::NAN, |s| a + b * s));
        let scatter = grid()
            .zip(&self.t_s)
            .map(|(g, t)| (t - t0 - g).abs())
            .fold(0.0, f64::max);
        // On the grid already (to the rounding of the times' text or of a large time origin):
        // nothing to do.
        if !scatter.is_finite() || scatter <= 1e-3 * period || scatter > CLOCK_JITTER_MAX * period {
            return None;
        }
        // Σ of squared second divided differences of θa at the given times.
        let rough = |times: &mut dyn Iterator<Item = f64>| -> f64 {
            let th = &self.theta_a_rad;
            let (mut r, mut w) = (0.0, [0.0; 3]);
            for (i, t) in times.enumerate() {
                w = [w[1], w[2], t];
                if i >= 2 {
                    let (h1, h2) = (w[1] - w[0], w[2] - w[1]);
                    if h1 > 0.0 && h2 > 0.0 {
                        let d1 = (th[i - 1] - th[i - 2]) / h1;
                        let d2 = (th[i] - th[i - 1]) / h2;
                        let dd = 2.0 * (d2 - d1) / (h1 + h2);
                        r += dd * dd;
                    }
                }
            }
            r
        };
        let r_logged = rough(&mut self.t_s.iter().map(|t| t - t0));
        let r_grid = rough(&mut grid());
        if r_grid.is_nan() || r_grid >= CLOCK_SMOOTHER * r_logged {
            return None;
        }
        // In place (the same slots again, from each row's time before it is replaced).
        let (mut slot, mut prev) = (0.0, t0);
        for (i, t) in self.t_s.iter_mut().enumerate() {
            if i > 0 {
                slot += ((*t - prev) / period).round();
            }
            prev = *t;
            *t = t0 + (a + b * slot);
        }
        Some(format!(
            "row times scatter by up to {:.3} ms about a regular {:.1} Hz grid, and θa is smoother \
             on the grid ({:.2} of the roughness at the logged times): read at the grid's times \
             (a logger's clock that jittered, not the sampling)",
            scatter * 1e3,
            1.0 / b,
            r_grid / r_logged
        ))
    }
}

/// Each row's slot on a grid of `period` (s) from the first row: the previous row's slot plus
/// its step rounded to periods; `None` from a row in the same slot as the one before.
fn slot_numbers(t_s: &[f64], period: f64) -> impl Iterator<Item = Option<f64>> + '_ {
    let mut slot = 0.0;
    let mut prev = t_s.first().copied().unwrap_or(0.0);
    t_s.iter().enumerate().map(move |(i, &t)| {
        if i > 0 {
            let k = ((t - prev) / period).round();
            if k.is_nan() || k < 1.0 {
                return None;
            }
            slot += k;
        }
        prev = t;
        Some(slot)
    })
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
    let mut rows = Vec::new();
    let mut warnings = Vec::new();
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
            (Some(t_s), Some(theta_a_rad), Some(torque_nm)) => rows.push(TraceRow {
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
        warnings.push(format!(
            "{bad} sample line(s) lacked a time, θa or torque and were skipped"
        ));
    }
    Trace::from_rows(&rows, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nm(i: f64) -> f64 {
        i * 2.0
    }

    /// A smooth closing motion (rad) at time t (s).
    fn closing(t: f64) -> f64 {
        -0.85 + 0.3 * t * t + 0.01 * (7.0 * t).sin()
    }

    /// A PCG-style generator of uniform draws in [−1, 1).
    fn draws(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (s >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
    }

    fn csv_of(rows: &[(f64, f64)]) -> String {
        let mut s = String::from("t_s,theta_a_rad,torque_nm\n");
        for (t, th) in rows {
            s += &format!("{t:?},{th:?},0.1\n");
        }
        s
    }

    /// Rows sampled every 1 ms (one in seven missing) and stamped with ±0.2 ms of jitter, from
    /// a clock 50 ppm fast, starting at 12.3 s: read at the grid's times, a constant apart from
    /// the true ones, with a warning that says so.
    #[test]
    fn a_jittered_logging_clock_is_read_at_its_grid() {
        let mut u = draws(3);
        let rows: Vec<(f64, f64)> = (0..1500)
            .filter(|i| i % 7 != 3)
            .map(|i| {
                let t = 1e-3 * f64::from(i);
                (12.3 + t * (1.0 + 50e-6) + 2e-4 * u(), closing(t))
            })
            .collect();
        let tr = read_csv(&csv_of(&rows), &nm).unwrap();
        let note = tr
            .warnings
            .iter()
            .find(|w| w.contains("regular"))
            .unwrap_or_else(|| panic!("no note: {:?}", tr.warnings));
        assert!(note.contains("1000.0 Hz"), "{note}");
        let truth: Vec<f64> = (0..1500)
            .filter(|i| i % 7 != 3)
            .map(|i| 12.3 + 1e-3 * f64::from(i) * (1.0 + 50e-6))
            .collect();
        // The line through 1285 times scattered by ±0.2 ms is known to a few µs at its ends.
        let offset = tr.t_s[0] - truth[0];
        for (t, g) in tr.t_s.iter().zip(&truth) {
            assert!((t - g - offset).abs() < 2e-5, "{t} vs {g} + {offset}");
        }
        assert!(offset.abs() < 1e-4, "offset {offset}");
    }

    /// Rows sampled at the jittered times themselves (θa is smooth at them), rows already on
    /// their grid (times as text with 3 decimals, or at a Unix time), and rows scattered by
    /// more than a third of a period: all left as they are.
    #[test]
    fn a_clock_that_is_right_is_left_alone() {
        let mut u = draws(5);
        let sampled: Vec<(f64, f64)> = (0..1500)
            .map(|i| {
                let t = 1e-3 * f64::from(i) + 2e-4 * u();
                (t, closing(t))
            })
            .collect();
        let on_grid: Vec<(f64, f64)> = (0..1500)
            .map(|i| {
                let t = 1e-3 * f64::from(i);
                (format!("{t:.3}").parse().unwrap(), closing(t))
            })
            .collect();
        let unix: Vec<(f64, f64)> = on_grid.iter().map(|(t, th)| (1.7e9 + t, *th)).collect();
        let scattered: Vec<(f64, f64)> = (0..1500)
            .map(|i| {
                let t = 1e-3 * f64::from(i);
                (t + 4e-4 * u(), closing(t))
            })
            .collect();
        for (what, rows) in [
            ("sampled at the logged times", sampled),
            ("on the grid", on_grid),
            ("at a Unix time", unix),
            ("scattered by ±0.4 periods", scattered),
        ] {
            let tr = read_csv(&csv_of(&rows), &nm).unwrap();
            assert!(tr.warnings.is_empty(), "{what}: {:?}", tr.warnings);
            let times: Vec<f64> = rows.iter().map(|r| r.0).collect();
            assert_eq!(tr.t_s, times, "{what}");
        }
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
        assert_eq!(t.to_rows(), rows);
        assert!(t.warnings.is_empty());
        assert_eq!(Trace::from_rows(&rows, vec![]).to_rows(), rows);
    }

    #[test]
    fn columns_sort_with_their_rows_and_only_the_file_s_columns_are_held() {
        let text = "t_s,theta_a_rad,torque_nm,state,encoder_count\n\
                    2,0.2,2,b,2\n1,0.1,1,a,\n3,0.3,3,,3\n1,0.15,1.5,b,7\n";
        let t = read_csv(text, &nm).unwrap();
        let rows = t.to_rows();
        let got: Vec<_> = rows
            .iter()
            .map(|r| (r.t_s, r.theta_a_rad, r.state.as_deref(), r.encoder_count))
            .collect();
        // Stable: the two rows at t = 1 keep their order.
        assert_eq!(
            got,
            [
                (1.0, 0.1, Some("a"), None),
                (1.0, 0.15, Some("b"), Some(7)),
                (2.0, 0.2, Some("b"), Some(2)),
                (3.0, 0.3, None, Some(3)),
            ]
        );
        assert!(t.warnings.iter().any(|w| w.contains("sorted")));
        assert!(t.opt.duty.is_none() && t.opt.true_k_m.is_none() && t.opt.true_contact.is_none());
        assert_eq!(t.opt.strings, ["b", "a"]);
        assert_eq!(Trace::from_rows(&rows, t.warnings.clone()).to_rows(), rows);
    }

    #[test]
    fn current_column_is_converted() {
        let t = read_csv("t_s,current_a,theta_a_rad\n0,0.5,-0.8\n", &nm).unwrap();
        assert_eq!(t.torque_nm[0], 1.0);
    }

    #[test]
    fn a_binary_header_is_quoted_escaped_and_cut() {
        let header = format!("{}\u{7}{}", "x".repeat(100), "y".repeat(100));
        let e = read_csv(&format!("{header}\n1,2\n"), &nm).unwrap_err();
        let quoted = e.split("it has: ").nth(1).expect("the header is quoted");
        assert!(!quoted.contains('\u{7}'), "{e}");
        assert!(
            quoted.starts_with(&format!("{}\\u{{7}}yyy", "x".repeat(100))),
            "{e}"
        );
        assert!(quoted.ends_with('…'), "{e}");
        // The bell becomes the five characters `\u{7}`; the ellipsis is one more.
        assert_eq!(quoted.chars().count(), SHOWN_HEADER_CHARS + 4 + 1, "{e}");
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
        assert_eq!(t.len(), 2);
        assert_eq!(t.t_s[0], 0.0);
        assert_eq!(t.warnings.len(), 2, "{:?}", t.warnings);
    }

    /// What spreadsheets and data frames write reads as the plain file: quoted fields, `;`
    /// with decimal commas, tabs, CRLF, a byte-order mark, time in ms or µs, θa in degrees.
    #[test]
    fn a_spreadsheet_s_csv_reads_as_the_plain_one() {
        let rows = [
            (0.0, -0.8503608106, 0.004652292),
            (0.003, -0.85, -0.0037),
            (1.25, -0.2238, 0.3566),
        ];
        let plain: String = std::iter::once("t_s,theta_a_rad,torque_nm\n".to_string())
            .chain(rows.iter().map(|(t, th, tq)| format!("{t},{th},{tq}\n")))
            .collect();
        let want = read_csv(&plain, &nm).unwrap();
        assert_eq!(want.len(), 3);
        assert_eq!((want.t_s[1], want.theta_a_rad[2]), (0.003, -0.2238));
        let variant = |hdr: [&str; 3], sep: &str, nl: &str, cell: &dyn Fn(usize, f64) -> String| {
            let mut s = format!("\u{feff}# exported\n{}{nl}", hdr.join(sep));
            for (t, th, tq) in rows {
                let r = [cell(0, t), cell(1, th), cell(2, tq)];
                s += &format!("{}{nl}", r.join(sep));
            }
            s
        };
        let hdr = ["t_s", "theta_a_rad", "torque_nm"];
        let cases: [(&str, String); 6] = [
            (
                "quoted",
                variant(
                    ["\"t_s\"", "\"theta_a_rad\"", "\"torque_nm\""],
                    ",",
                    "\n",
                    &|_, v| format!("\"{v}\""),
                ),
            ),
            (
                "semicolon, decimal comma",
                variant(hdr, ";", "\r\n", &|_, v| format!("{v}").replace('.', ",")),
            ),
            ("tab", variant(hdr, "\t", "\n", &|_, v| format!("{v}"))),
            (
                "t_ms",
                variant(["t_ms", hdr[1], hdr[2]], ",", "\n", &|i, v| {
                    if i == 0 {
                        format!("{}", v * 1e3)
                    } else {
                        format!("{v}")
                    }
                }),
            ),
            (
                "t_us",
                variant(["t_us", hdr[1], hdr[2]], ",", "\n", &|i, v| {
                    if i == 0 {
                        format!("{}", (v * 1e6).round())
                    } else {
                        format!("{v}")
                    }
                }),
            ),
            (
                "theta_a_deg",
                variant([hdr[0], "theta_a_deg", hdr[2]], ",", "\n", &|i, v| {
                    if i == 1 {
                        format!("{}", v.to_degrees())
                    } else {
                        format!("{v}")
                    }
                }),
            ),
        ];
        for (what, text) in cases {
            let got = read_csv(&text, &nm).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert!(got.warnings.is_empty(), "{what}: {:?}", got.warnings);
            assert_eq!(got.t_s, want.t_s, "{what}: times");
            assert_eq!(got.torque_nm, want.torque_nm, "{what}: torque");
            for (a, b) in got.theta_a_rad.iter().zip(&want.theta_a_rad) {
                assert!((a - b).abs() < 1e-15, "{what}: θa {a} vs {b}");
            }
        }
        // In a comma-separated file a decimal comma is a field separator: the row is too long,
        // its numbers wrong, and the unusable cell is named.
        let e = read_csv("t_s,theta_a_rad,torque_nm\n0,001,-0,85,0\n", &nm).unwrap();
        assert_eq!((e.t_s[0], e.theta_a_rad[0]), (0.0, 1.0));
        let e = read_csv("t_s;theta_a_rad;torque_nm\n0,0,1;-0,85;0\n", &nm).unwrap_err();
        assert!(e.contains("line 2: t_s = \"0,0,1\""), "{e}");
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
        let r = &t.to_rows()[0];
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
        let rows = t.to_rows();
        assert_eq!(rows.len(), 2, "{rows:?}");
        assert!((rows[0].t_s - 0.04).abs() < 1e-15);
        assert!((rows[0].theta_a_rad - -0.85036).abs() < 1e-15);
        assert_eq!(rows[0].duty, Some(-0.5));
        assert_eq!(rows[0].state.as_deref(), Some("approach"));
        assert_eq!(rows[1].state.as_deref(), Some("fault"));
        assert_eq!(t.warnings.len(), 1);
        // An explicit period wins over the BOOT line.
        let t = from_defmt(log, Some(1e-3), &nm);
        assert!((t.t_s[0] - 0.2).abs() < 1e-12);
    }
}
