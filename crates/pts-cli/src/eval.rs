//! `pts eval`: the batch evaluator. One JSON request per line in, one JSON answer per line out.
//!
//! Every line gets exactly one answer, in order. A line that cannot be answered gets
//! `{"ok":false,"error":"<kind>","message":"…"}` and the stream goes on. `kind` is
//! [`pts::PtsError::kind`] for model failures, `bad_request` for malformed input, and the
//! plant's names (`second_contact`, `beyond_tip`, `loss_of_contact`, …) for the `path` op.

use pts::{Config, Finger, Model, Real};
use serde_json::{Map, Value};

/// Which numeric back end answers the requests.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Numeric {
    /// The f64 reference model.
    F64,
    /// The firmware's fixed-point back end.
    Fixed,
}

/// A failed request: a snake_case kind and a human message.
#[derive(Debug, Clone, PartialEq)]
pub struct Fail {
    /// snake_case kind (`bad_request`, `not_assemblable`, …).
    pub kind: String,
    /// What went wrong, for a person.
    pub message: String,
}

impl Fail {
    /// A malformed request.
    pub fn bad(message: impl Into<String>) -> Self {
        Fail {
            kind: "bad_request".into(),
            message: message.into(),
        }
    }
}

impl From<pts::PtsError> for Fail {
    fn from(e: pts::PtsError) -> Self {
        Fail {
            kind: e.kind().into(),
            message: e.to_string(),
        }
    }
}

type Answer = Result<Map<String, Value>, Fail>;

/// The fields each op takes (besides `op`, `id`, `K1`, `K2`).
fn fields_of(op: &str) -> Option<&'static [&'static str]> {
    Some(match op {
        "closure" => &["theta1", "theta2"],
        "kc" => &["theta1", "theta2", "ta", "phalanx", "k"],
        "free" => &["ta"],
        "invert" => &["theta1", "theta2", "ta", "kc"],
        "estimate" => &["theta_a_c", "ta_c", "theta_a", "ta"],
        "path" => &["theta1_c", "phalanx", "k_c", "radius", "dta"],
        _ => return None,
    })
}

/// A parsed request: the op and its numeric fields, all finite.
struct Request<'a> {
    op: &'a str,
    obj: &'a Map<String, Value>,
}

impl Request<'_> {
    fn num(&self, key: &str) -> Result<f64, Fail> {
        match self.obj.get(key) {
            None => Err(Fail::bad(format!(
                "op \"{}\" needs field \"{key}\"",
                self.op
            ))),
            Some(Value::Number(n)) => match n.as_f64() {
                Some(x) if x.is_finite() => Ok(x),
                _ => Err(Fail::bad(format!("field \"{key}\" is not a finite number"))),
            },
            Some(other) => Err(Fail::bad(format!(
                "field \"{key}\" must be a number, got {}",
                type_name(other)
            ))),
        }
    }

    fn opt_num(&self, key: &str) -> Result<Option<f64>, Fail> {
        if self.obj.contains_key(key) {
            self.num(key).map(Some)
        } else {
            Ok(None)
        }
    }

    fn phalanx(&self) -> Result<u8, Fail> {
        match self.obj.get("phalanx") {
            None => Err(Fail::bad(format!(
                "op \"{}\" needs field \"phalanx\" (1 or 2)",
                self.op
            ))),
            Some(Value::Number(n)) => match n.as_u64() {
                Some(1) => Ok(1),
                Some(2) => Ok(2),
                _ => Err(Fail::bad(format!(
                    "field \"phalanx\" must be 1 (proximal) or 2 (distal), got {n}"
                ))),
            },
            Some(other) => Err(Fail::bad(format!(
                "field \"phalanx\" must be 1 or 2, got {}",
                type_name(other)
            ))),
        }
    }
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// The evaluator: a finger and a back end.
pub struct Evaluator {
    finger: Finger,
    numeric: Numeric,
}

impl Evaluator {
    /// An evaluator for this finger on this back end.
    pub fn new(finger: Finger, numeric: Numeric) -> Self {
        Evaluator { finger, numeric }
    }

    /// Answers one line: always one JSON object, never NaN.
    pub fn eval_line(&self, line: &str) -> String {
        let parsed: Result<Value, _> = serde_json::from_str(line);
        let (id, answer) = match parsed {
            Err(e) => (None, Err(Fail::bad(format!("not JSON: {e}")))),
            Ok(Value::Object(obj)) => (obj.get("id").cloned(), self.eval_object(&obj)),
            Ok(other) => (
                None,
                Err(Fail::bad(format!(
                    "a request must be a JSON object, got {}",
                    type_name(&other)
                ))),
            ),
        };
        render(id, answer)
    }

    /// The answer to a line that is not valid UTF-8.
    pub fn not_utf8(&self) -> String {
        render(None, Err(Fail::bad("the line is not valid UTF-8")))
    }

    fn eval_object(&self, obj: &Map<String, Value>) -> Answer {
        let op = match obj.get("op") {
            Some(Value::String(s)) => s.as_str(),
            Some(other) => {
                return Err(Fail::bad(format!(
                    "field \"op\" must be a string, got {}",
                    type_name(other)
                )))
            }
            None => return Err(Fail::bad("missing field \"op\"")),
        };
        let Some(fields) = fields_of(op) else {
            return Err(Fail::bad(format!(
                "unknown op \"{op}\" (closure, kc, free, invert, estimate, path)"
            )));
        };
        for key in obj.keys() {
            let known =
                matches!(key.as_str(), "op" | "id" | "K1" | "K2") || fields.contains(&key.as_str());
            if !known {
                let hint = match key.as_str() {
                    "k1" | "k2" => " (joint springs are \"K1\"/\"K2\", capital K)",
                    _ => "",
                };
                return Err(Fail::bad(format!(
                    "unknown field \"{key}\" for op \"{op}\"{hint}; it takes {}",
                    fields.join(", ")
                )));
            }
        }
        let req = Request { op, obj };
        let mut finger = self.finger;
        if let Some(k1) = req.opt_num("K1")? {
            finger.k1 = k1;
        }
        if let Some(k2) = req.opt_num("K2")? {
            finger.k2 = k2;
        }
        // Read every field first: a malformed request is bad_request whatever the model says.
        let values: Vec<f64> = fields
            .iter()
            .filter(|k| **k != "phalanx")
            .map(|k| req.num(k))
            .collect::<Result<_, _>>()?;
        let phalanx = if fields.contains(&"phalanx") {
            Some(req.phalanx()?)
        } else {
            None
        };
        if op == "path" {
            return crate::path::answer(&finger, phalanx.unwrap_or(0), &values);
        }
        let answer = match self.numeric {
            Numeric::F64 => answer::<f64>(&finger, op, phalanx, &values),
            Numeric::Fixed => answer::<crate::FixedReal>(&finger, op, phalanx, &values),
        }?;
        // JSON has no NaN: never print one.
        for (k, v) in &answer {
            if let Value::Number(n) = v {
                if !n.as_f64().is_some_and(f64::is_finite) {
                    return Err(Fail {
                        kind: "non_finite".into(),
                        message: format!("result \"{k}\" is not finite"),
                    });
                }
            }
        }
        Ok(answer)
    }
}

/// Renders an answer as one JSON line (no trailing newline).
fn render(id: Option<Value>, answer: Answer) -> String {
    let mut out = Map::new();
    if let Some(id) = id {
        out.insert("id".into(), id);
    }
    match answer {
        Ok(fields) => {
            out.insert("ok".into(), Value::Bool(true));
            out.extend(fields);
        }
        Err(f) => {
            out.insert("ok".into(), Value::Bool(false));
            out.insert("error".into(), Value::String(f.kind));
            out.insert("message".into(), Value::String(f.message));
        }
    }
    Value::Object(out).to_string()
}

/// A JSON number from an f64; `None` (→ error) when non-finite.
pub fn num(x: f64) -> Value {
    serde_json::Number::from_f64(x).map_or(Value::Null, Value::Number)
}

fn out_of_range(x: f64) -> Fail {
    Fail {
        kind: "out_of_range".into(),
        message: format!("{x} cannot be represented by this numeric back end"),
    }
}

fn conv<R: Real>(x: f64) -> Result<R, Fail> {
    R::try_from_f64(x).ok_or_else(|| out_of_range(x))
}

fn finite_out<R: Real>(key: &str, x: R) -> Result<(String, Value), Fail> {
    let v = x.to_f64();
    if !v.is_finite() {
        return Err(Fail {
            kind: "non_finite".into(),
            message: format!("result \"{key}\" is not finite"),
        });
    }
    Ok((key.to_string(), num(v)))
}

fn put<R: Real>(out: &mut Map<String, Value>, key: &str, x: R) -> Result<(), Fail> {
    let (k, v) = finite_out(key, x)?;
    out.insert(k, v);
    Ok(())
}

fn answer<R: Real>(finger: &Finger, op: &str, phalanx: Option<u8>, v: &[f64]) -> Answer {
    let model = Model::<R>::new(finger)?;
    let mut out = Map::new();
    match (op, v) {
        ("closure", &[theta1, theta2]) => {
            let (t1, t2) = (conv::<R>(theta1)?, conv::<R>(theta2)?);
            let cl = model.closure(t2)?;
            let theta_a = model.theta_a(t1, t2)?;
            put(&mut out, "gamma", cl.gamma)?;
            put(&mut out, "theta_a", theta_a)?;
            put(&mut out, "x2", cl.x2)?;
            put(&mut out, "dx2", cl.dx2)?;
        }
        ("kc", &[theta1, theta2, ta, k]) => {
            let (t1, t2, ta) = (conv::<R>(theta1)?, conv::<R>(theta2)?, conv::<R>(ta)?);
            // θ1 does not enter K_c, but it must describe a configuration.
            model.theta_a(t1, t2)?;
            let kc = if phalanx == Some(1) {
                if !(k > 0.0 && k <= finger.l1) {
                    return Err(pts::PtsError::ContactOutsidePhalanx.into());
                }
                model.kc_proximal(t2, ta)?
            } else {
                model.kc_distal(t2, ta, conv::<R>(k)?)?
            };
            put(&mut out, "kc", kc)?;
        }
        ("free", &[ta]) => {
            let cfg = model.free_from_torque(conv::<R>(ta)?)?;
            let kc = model.kc_free(cfg.theta2, cfg.ta)?;
            put(&mut out, "theta1", cfg.theta1)?;
            put(&mut out, "theta2", cfg.theta2)?;
            put(&mut out, "theta_a", cfg.theta_a)?;
            put(&mut out, "kc", kc)?;
        }
        ("invert", &[theta1, theta2, ta, kc]) => {
            let (t1, t2, ta) = (conv::<R>(theta1)?, conv::<R>(theta2)?, conv::<R>(ta)?);
            let cl = model.closure(t2)?;
            let cfg = Config {
                theta1: t1,
                theta2: t2,
                theta_a: model.theta_a(t1, t2)?,
                ta,
                x2: cl.x2,
                dx2: cl.dx2,
            };
            let c = model.invert(&cfg, conv::<R>(kc)?)?;
            out.insert("phalanx".into(), Value::String(c.phalanx.name().into()));
            out.insert(
                "k2".into(),
                match c.k2 {
                    Some(k2) => finite_out("k2", k2)?.1,
                    None => Value::Null,
                },
            );
        }
        ("estimate", &[theta_a_c, ta_c, theta_a, ta]) => {
            let e = model.estimate_two_point(
                conv::<R>(theta_a_c)?,
                conv::<R>(ta_c)?,
                conv::<R>(theta_a)?,
                conv::<R>(ta)?,
            )?;
            put(&mut out, "kc_hat", e.kc_hat)?;
            out.insert(
                "phalanx".into(),
                Value::String(e.contact.phalanx.name().into()),
            );
            out.insert(
                "k2".into(),
                match e.contact.k2 {
                    Some(k2) => finite_out("k2", k2)?.1,
                    None => Value::Null,
                },
            );
            put(&mut out, "theta1_c", e.contact_config.theta1)?;
            put(&mut out, "theta2_c", e.contact_config.theta2)?;
        }
        _ => return Err(Fail::bad(format!("op \"{op}\" is not answered here"))),
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev() -> Evaluator {
        Evaluator::new(Finger::PAPER, Numeric::F64)
    }

    fn parse(s: &str) -> Map<String, Value> {
        match serde_json::from_str(s).unwrap() {
            Value::Object(m) => m,
            _ => panic!("not an object: {s}"),
        }
    }

    #[test]
    fn id_is_echoed_and_ok_comes_first() {
        let out = ev().eval_line(r#"{"id":7,"op":"free","ta":0}"#);
        assert!(out.starts_with(r#"{"id":7,"ok":true"#), "{out}");
    }

    #[test]
    fn lower_case_spring_gets_a_hint() {
        let out = parse(&ev().eval_line(r#"{"op":"free","ta":0,"k1":1}"#));
        assert_eq!(out["error"], "bad_request");
        assert!(out["message"].as_str().unwrap().contains("capital K"));
    }
}

/// Longest request line `pts eval` reads (bytes); a longer line ends the stream with an error
/// naming the limit instead of growing without bound (`pts eval < /dev/zero`).
pub const LINE_MAX_BYTES: usize = 64 * 1024;

/// Reads one line (without its `\n`/`\r\n`) into `buf`, at most `limit` bytes. `Ok(false)`
/// at the end of the input; an error naming the limit for a longer line.
pub fn read_line_limited(
    r: &mut impl std::io::BufRead,
    buf: &mut Vec<u8>,
    limit: usize,
) -> Result<bool, String> {
    use std::io::{BufRead, Read};
    buf.clear();
    // Room for the content, `\r` and `\n`: a longer line stops here, unread past it.
    let n = r
        .take(limit as u64 + 2)
        .read_until(b'\n', buf)
        .map_err(|e| format!("reading stdin: {e}"))?;
    if n == 0 {
        return Ok(false);
    }
    let newline = buf.last() == Some(&b'\n');
    if newline {
        buf.pop();
    }
    if buf.last() == Some(&b'\r') {
        buf.pop();
    }
    if buf.len() > limit || (!newline && n == limit + 2) {
        return Err(format!(
            "a request line is longer than the {limit}-byte limit of `pts eval`"
        ));
    }
    Ok(true)
}

#[cfg(test)]
mod line_limit_tests {
    use super::*;

    #[test]
    fn lines_up_to_the_limit_pass_and_a_longer_one_is_refused_naming_it() {
        let mut buf = Vec::new();
        let mut ok = std::io::Cursor::new(b"abcd\r\nxy\nlast".to_vec());
        assert!(read_line_limited(&mut ok, &mut buf, 4).unwrap());
        assert_eq!(buf, b"abcd");
        assert!(read_line_limited(&mut ok, &mut buf, 4).unwrap());
        assert_eq!(buf, b"xy");
        assert!(read_line_limited(&mut ok, &mut buf, 4).unwrap());
        assert_eq!(buf, b"last");
        assert!(!read_line_limited(&mut ok, &mut buf, 4).unwrap());
        // An endless line (as from /dev/zero) stops at the limit.
        use std::io::Read;
        let mut zeros = std::io::repeat(0).take(1 << 20);
        let mut r = std::io::BufReader::new(&mut zeros);
        let e = read_line_limited(&mut r, &mut buf, 1000).unwrap_err();
        assert!(e.contains("1000-byte limit"), "{e}");
        assert!(buf.len() <= 1002);
    }
}
