//! CSV traces (std feature): one row per recorded control period.
//!
//! Columns: `t_s, theta_a_true_rad, theta_a_meas_rad, torque_true_nm, torque_meas_nm,
//! current_a, encoder_count, adc_code, contact, k_m, theta1_rad, theta2_rad, force, events`.
//! "meas" values are what a controller would compute from the encoder and the ADC with the
//! nominal constants (θa,rest + count·2π/(4·CPT·N); N·η·kt·i). `events` lists the event names
//! of that period separated by `|`.

use std::io::{self, Write};

use crate::scene::Scene;
use crate::{Event, Plant, PlantError};

/// The CSV header line (without newline).
pub const HEADER: &str = "t_s,theta_a_true_rad,theta_a_meas_rad,torque_true_nm,torque_meas_nm,current_a,encoder_count,adc_code,contact,k_m,theta1_rad,theta2_rad,force,events";

/// Writes the header.
pub fn write_header(w: &mut dyn Write) -> io::Result<()> {
    writeln!(w, "{HEADER}")
}

/// Writes one row for the plant's current state and the events of the period.
pub fn write_row(w: &mut dyn Write, p: &Plant, events: &[Event]) -> io::Result<()> {
    let t = p.truth();
    write!(
        w,
        "{:.6},{:.9},{:.9},{:.6},{:.6},{:.6},{},{},{},{:.6},{:.9},{:.9},{:.6},",
        t.t_s,
        t.theta_a_rad,
        p.measured_theta_a_rad(),
        t.torque_a_nm,
        p.measured_torque_nm(),
        t.current_a,
        p.encoder_count(),
        p.current_adc(),
        t.contact.name(),
        t.k_m,
        t.theta1_rad,
        t.theta2_rad,
        t.force
    )?;
    for (i, e) in events.iter().enumerate() {
        if i > 0 {
            write!(w, "|")?;
        }
        write!(w, "{}", e.kind.name())?;
    }
    writeln!(w)
}

/// Runs `scene` open-loop (its command profile) for its duration and writes the trace,
/// one row every `decimate` periods (rows with events are always written).
/// Returns the number of rows written.
pub fn run_scene_csv(scene: &Scene, w: &mut dyn Write, decimate: u32) -> Result<u64, TraceError> {
    let mut p = Plant::new(scene).map_err(TraceError::Plant)?;
    write_header(w).map_err(TraceError::Io)?;
    write_row(w, &p, &[]).map_err(TraceError::Io)?;
    let steps = (scene.duration_s / scene.dt_s).round() as u64;
    let dec = u64::from(decimate.max(1));
    let mut rows = 1u64;
    let mut evs: std::vec::Vec<Event> = std::vec::Vec::new();
    for i in 1..=steps {
        p.step_scene();
        evs.clear();
        while let Some(e) = p.poll_event() {
            evs.push(e);
        }
        if i % dec == 0 || !evs.is_empty() {
            write_row(w, &p, &evs).map_err(TraceError::Io)?;
            rows += 1;
        }
    }
    Ok(rows)
}

/// Failure of [`run_scene_csv`].
#[derive(Debug)]
pub enum TraceError {
    /// The scene was rejected.
    Plant(PlantError),
    /// Writing failed.
    Io(io::Error),
}

impl core::fmt::Display for TraceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TraceError::Plant(e) => write!(f, "scene: {e}"),
            TraceError::Io(e) => write!(f, "write: {e}"),
        }
    }
}

impl std::error::Error for TraceError {}
