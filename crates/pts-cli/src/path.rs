//! `pts eval` op "path": the plant's quasi-static path after contact.

use crate::eval::Fail;
use pts::Finger;
use serde_json::{Map, Value};

/// Answers a path request: `values` = [theta1_c, k_c, radius, dta], `phalanx` 1 or 2.
pub fn answer(_finger: &Finger, _phalanx: u8, _values: &[f64]) -> Result<Map<String, Value>, Fail> {
    Err(Fail {
        kind: "unsupported".into(),
        message: "the plant's quasi-static path is not available in this build".into(),
    })
}
