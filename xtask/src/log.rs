//! The firmware's log lines (src/telemetry.rs) parsed back: `S` samples, `E` controller events,
//! `P` plant events, `TRUTH`, `END`. The field readers and the line formats are `proto::log`'s,
//! shared with the firmware and `pts trace`.

pub use proto::log::{int, word};

use crate::qemu::Frame;

/// One line for the terminal.
pub fn show(f: &Frame) -> String {
    match f.ts {
        Some(ts) => format!("{ts:>8} {:<5} {}", f.level, f.msg),
        None => format!("{:<5} {}", f.level, f.msg),
    }
}

/// Controller event names (`E Name { .. }`), in order.
pub fn events(frames: &[Frame]) -> Vec<String> {
    frames
        .iter()
        .filter_map(|f| proto::log::event_name(&f.msg))
        .map(str::to_string)
        .collect()
}

/// The first frame whose message starts with `prefix`.
pub fn first<'a>(frames: &'a [Frame], prefix: &str) -> Option<&'a Frame> {
    frames.iter().find(|f| f.msg.starts_with(prefix))
}

/// The last frame whose message starts with `prefix`.
pub fn last<'a>(frames: &'a [Frame], prefix: &str) -> Option<&'a Frame> {
    frames.iter().rev().find(|f| f.msg.starts_with(prefix))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(msg: &str) -> Frame {
        Frame {
            ts: None,
            level: "INFO".into(),
            msg: msg.into(),
        }
    }

    #[test]
    fn int_reads_key_value_and_struct_fields() {
        let m = "E Estimated { tick: 53244, result: EstimateResult { located: Distal, k2_um: Some(50250), kc_hat_unm_per_rad: 13301498 } }";
        assert_eq!(int(m, "k2_um"), Some(50250));
        assert_eq!(int(m, "tick"), Some(53244));
        assert_eq!(int(m, "kc_hat_unm_per_rad"), Some(13301498));
        // `um` alone must not match inside `k2_um`.
        assert_eq!(int(m, "um"), None);
        let s = "END status=2 state=Fault(Stall) bridge_safe=true ticks=14001 work_max=-3";
        assert_eq!(int(s, "status"), Some(2));
        assert_eq!(int(s, "work_max"), Some(-3));
        assert_eq!(int(s, "missing"), None);
        assert_eq!(int("k2_um: None", "k2_um"), None);
    }

    #[test]
    fn word_and_events() {
        let s = "END status=2 state=Fault(Stall) bridge_safe=true ticks=1";
        assert_eq!(word(s, "state"), Some("Fault(Stall)"));
        assert_eq!(word(s, "bridge_safe"), Some("true"));
        let frames = [
            frame("BOOT x"),
            frame("E Calibrated { tick: 200, offset_q8: 1 }"),
            frame("S tick=200"),
            frame("E Fault { tick: 9, reason: Stall }"),
            frame("E Holding { tick: 10 }"),
        ];
        assert_eq!(events(&frames), ["Calibrated", "Fault", "Holding"]);
        assert_eq!(
            first(&frames, "E ").map(|f| f.msg.as_str()),
            Some("E Calibrated { tick: 200, offset_q8: 1 }")
        );
        assert_eq!(
            last(&frames, "E ").map(|f| f.msg.as_str()),
            Some("E Holding { tick: 10 }")
        );
    }
}
