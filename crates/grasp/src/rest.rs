//! The rest pose found before the encoder is zeroed (homing).
//!
//! The encoder is incremental: its reading means nothing until it is tied to a pose. Zeroing it
//! at power-up assumes the finger is at rest there; a finger powered up flexed (after a reset
//! mid-grasp, or moved by hand) would then carry that error into every θa, and the estimate
//! with it, with nothing to show it. So, before the current calibration, [`RestCheck`] drives a
//! gentle opening torque until the actuator is against the finger's open stop (both joints on
//! their extension stops), where the pose is known from the geometry, and zeroes there:
//!
//! 1. **Opening**: duty `−open_duty`. Its torque is bounded at any speed by the stall value
//!    N·η·kt·V·d/R (back-EMF only lowers it), chosen above the springs' torque at the stop and
//!    well below the grasp's.
//! 2. **At the stop** when, for `still_ticks`, the count moved by at most `still_counts` and
//!    the winding carries at least 85 % of the stall current (no back-EMF: the motor is not
//!    turning, so a stuck encoder over a turning motor is not taken for the stop, and the
//!    stop carries the torque its compliance was computed for).
//! 3. **Zero**: the count there is the stop's, `stop_counts` from the rest (the geometry's
//!    angle, less the stop's compliance under the opening torque and half the backlash: the
//!    encoder is on the motor, whose gear now sits on its opening flank).
//! 4. **Returning**: duty `+return_duty` until θa is back at the rest (within
//!    `return_counts`), then the bridge off: the approach starts from rest as without the check.
//!
//! Refused with [`FaultReason::RestNotFound`] (bridge off) when no stop is found within
//! `timeout_ticks` or `max_travel_counts` of opening travel, or the return does not reach the
//! rest within `timeout_ticks`. The [`RestReport`] tells how far from rest the finger was at
//! power-up. Integer only, no division, no panic.
#![deny(clippy::float_arithmetic)]

use crate::config::{ConfigError, DriveConfig};
use crate::state::FaultReason;
use crate::DUTY_MAX;

/// The rest check's settings, SI units (converted once by [`RestCheck::params`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestCheck {
    /// Largest opening torque at the base link (N·m): the stall torque of the opening duty.
    pub open_torque_nm: f64,
    /// Largest closing torque of the return to rest (N·m, stall torque of its duty).
    pub return_torque_nm: f64,
    /// θa of the open stop relative to the rest, with no load (rad, negative: opening).
    pub stop_from_rest_rad: f64,
    /// The springs' torque at the stop (N·m at the base link, opening, ≥ 0): the part of the
    /// opening torque the finger's springs take; the stop carries the rest.
    pub stop_spring_nm: f64,
    /// The transmission's friction at the base link (N·m, ≥ 0): the stalled motor's torque
    /// that does not reach the finger.
    pub friction_nm: f64,
    /// Compliance of the finger against the open stop (rad per N·m at the base link): the
    /// torque the stop carries moves it by this much further.
    pub stop_compliance_rad_per_nm: f64,
    /// Backlash between the motor (the encoder) and the finger (rad at the base link): at the
    /// stop the gear sits on its opening flank, half of it beyond the finger; at the
    /// encoder's zero (the rest, as a finger powered up there) it sits in the middle.
    pub backlash_rad: f64,
    /// Time without motion that marks the stop (s).
    pub still_s: f64,
    /// Largest θa change over `still_s` that still counts as no motion (rad).
    pub still_rad: f64,
    /// No stop within this time, or no return to rest within it: refused (s).
    pub timeout_s: f64,
    /// No stop within this opening travel: refused (rad; the finger's whole range).
    pub max_travel_rad: f64,
    /// The return ends this close to the rest (rad).
    pub return_band_rad: f64,
}

impl RestCheck {
    /// For the paper finger on the prototype drive: the stop 0.08153 rad below the rest
    /// (θ1 = π/4 − 0.05, θ2 = −0.05, see the plant's `FingerGeom::PAPER`), where the springs
    /// take 0.0444 N·m, 200 N·m/rad against it, 0.076 N·m of transmission friction (the
    /// motor's Coulomb friction through the gear), 3 mrad of backlash; 0.5 N·m opening (the springs need ≈ 0.2 N·m plus the transmission's friction),
    /// 0.8 N·m back (free motion, nothing to hit); 10 s for either phase: at 0.5 N·m the
    /// drive opens at ≈ 0.07 rad/s, so a finger powered up 0.6 rad flexed still homes.
    pub const PAPER: RestCheck = RestCheck {
        open_torque_nm: 0.5,
        return_torque_nm: 0.8,
        stop_from_rest_rad: -0.081_53,
        stop_spring_nm: 0.044_4,
        friction_nm: 0.076,
        stop_compliance_rad_per_nm: 1.0 / 200.0,
        backlash_rad: 3e-3,
        still_s: 0.1,
        still_rad: 1e-4,
        timeout_s: 10.0,
        max_travel_rad: 2.5,
        return_band_rad: 2e-3,
    };

    /// The integer form for a drive.
    #[allow(clippy::float_arithmetic)] // once, at configuration
    pub fn params(&self, d: &DriveConfig) -> Result<RestParams, ConfigError> {
        let vals = [
            self.open_torque_nm,
            self.return_torque_nm,
            self.stop_from_rest_rad,
            self.stop_spring_nm,
            self.friction_nm,
            self.stop_compliance_rad_per_nm,
            self.backlash_rad,
            self.still_s,
            self.still_rad,
            self.timeout_s,
            self.max_travel_rad,
            self.return_band_rad,
        ];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err(ConfigError::NonFinite);
        }
        if !(self.open_torque_nm > 0.0
            && self.return_torque_nm > 0.0
            && self.stop_from_rest_rad < 0.0
            && self.stop_compliance_rad_per_nm >= 0.0
            && self.stop_spring_nm >= 0.0
            && self.friction_nm >= 0.0
            && self.stop_spring_nm + self.friction_nm < self.open_torque_nm
            && self.backlash_rad >= 0.0
            && self.still_s > 0.0
            && self.still_rad > 0.0
            && self.timeout_s > self.still_s
            && self.max_travel_rad > -self.stop_from_rest_rad
            && self.return_band_rad > 0.0)
        {
            return Err(ConfigError::OutOfRange);
        }
        // Stall torque at full duty: N·η·kt·V/R (N·m).
        let stall_full_nm = d.torque_per_amp() * d.bus_v / d.resistance_ohm;
        let duty = |nm: f64| duty_of(nm, stall_full_nm);
        let open_duty = duty(self.open_torque_nm)?;
        let rpc = d.rad_per_count();
        let counts = |rad: f64| counts_of(rad, rpc);
        let ticks = |secs: f64| ticks_of(secs, d.dt_s);
        // The torque the stop carries once the motor stands: the opening duty's stall value.
        let stall_nm = f64::from(open_duty) / f64::from(DUTY_MAX) * stall_full_nm;
        let stall_ua = stall_nm / d.torque_per_amp() * 1e6;
        Ok(RestParams {
            open_duty,
            return_duty: duty(self.return_torque_nm)?,
            stop_counts: counts(
                self.stop_from_rest_rad
                    - (stall_nm - self.stop_spring_nm - self.friction_nm).max(0.0)
                        * self.stop_compliance_rad_per_nm
                    - 0.5 * self.backlash_rad,
            )?,
            still_counts: counts(self.still_rad)?.max(1),
            still_ticks: ticks(self.still_s)?,
            timeout_ticks: ticks(self.timeout_s)?,
            max_travel_counts: counts(self.max_travel_rad)?,
            return_counts: counts(self.return_band_rad)?.max(1),
            stall_ua_min: (stall_ua * 0.85) as i32,
        })
    }
}

// The conversions of [`RestCheck::params`], out of line: called several times each, once
// per grasp, so one copy of each soft-float sequence is enough.

/// A torque (N·m) as duty ([`DUTY_MAX`] units) of a drive stalling at `stall_full_nm` at
/// full duty: at least 1, at most full duty.
#[inline(never)]
#[allow(clippy::float_arithmetic)] // once, at configuration
fn duty_of(nm: f64, stall_full_nm: f64) -> Result<i16, ConfigError> {
    let x = nm / stall_full_nm * f64::from(DUTY_MAX);
    if x.is_finite() && x >= 1.0 && x <= f64::from(DUTY_MAX) {
        Ok(x as i16)
    } else {
        Err(ConfigError::OutOfRange)
    }
}

/// An angle (rad) as encoder counts of `rad_per_count` (rad), truncated; below 10⁹ in size.
#[inline(never)]
#[allow(clippy::float_arithmetic)] // once, at configuration
fn counts_of(rad: f64, rad_per_count: f64) -> Result<i32, ConfigError> {
    let c = rad / rad_per_count;
    if c.is_finite() && c.abs() < 1e9 {
        Ok(c as i32)
    } else {
        Err(ConfigError::OutOfRange)
    }
}

/// A duration (s) as control ticks of `dt_s` (s), truncated; at least 1, below 4·10⁹.
#[inline(never)]
#[allow(clippy::float_arithmetic)] // once, at configuration
fn ticks_of(secs: f64, dt_s: f64) -> Result<u32, ConfigError> {
    let t = secs / dt_s;
    if t.is_finite() && (1.0..4e9).contains(&t) {
        Ok(t as u32)
    } else {
        Err(ConfigError::OutOfRange)
    }
}

/// [`RestCheck`] in integer form: counts, ticks, duty ([`DUTY_MAX`] units), µA.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RestParams {
    /// Opening duty (positive number, applied negative).
    pub open_duty: i16,
    /// Closing duty of the return.
    pub return_duty: i16,
    /// The stop's count relative to the rest, under the opening torque (negative).
    pub stop_counts: i32,
    /// Largest count change over `still_ticks` that is no motion.
    pub still_counts: i32,
    /// Ticks without motion that mark the stop.
    pub still_ticks: u32,
    /// Longest opening, and longest return (ticks).
    pub timeout_ticks: u32,
    /// Longest opening travel (counts).
    pub max_travel_counts: i32,
    /// The return ends this close to the rest (counts).
    pub return_counts: i32,
    /// Least |current| at the stop (µA): 85 % of the opening duty's stall current.
    pub stall_ua_min: i32,
}

/// What the check found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RestReport {
    /// θa at power-up relative to the rest (counts; 0: powered up at rest, positive: flexed).
    pub power_up_counts: i32,
    /// The same in µrad (filled in by the control loop, which knows the encoder's scale).
    pub power_up_urad: i32,
    /// Ticks from the start of the check to the stop.
    pub stop_ticks: u32,
    /// Ticks from the start of the check to the end of the return.
    pub done_ticks: u32,
}

/// What the loop does this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RestStep {
    /// Apply this duty.
    Drive(i16),
    /// The stop is found: the encoder's count becomes `counts_from_rest` now (the count
    /// passed in this tick is that pose); then apply `duty`.
    Zero {
        /// The count of this pose relative to the rest.
        counts_from_rest: i32,
        /// Duty to apply.
        duty: i16,
    },
    /// Back at rest: bridge off, the check is over.
    Finished(RestReport),
    /// Refused: bridge off.
    Refused(FaultReason),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Opening,
    Returning,
    Over,
}

/// The check's state machine: one [`RestCheck`] step per control tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RestState {
    p: RestParams,
    phase: Phase,
    ticks: u32,
    /// Count and tick where the current no-motion window started.
    anchor_counts: i32,
    anchor_tick: u32,
    start_counts: i32,
    power_up_counts: i32,
    stop_ticks: u32,
    return_from: u32,
}

impl RestState {
    /// Before the first tick; `counts` is the reading at power-up.
    pub fn new(p: RestParams, counts: i32) -> Self {
        Self {
            p,
            phase: Phase::Opening,
            ticks: 0,
            anchor_counts: counts,
            anchor_tick: 0,
            start_counts: counts,
            power_up_counts: 0,
            stop_ticks: 0,
            return_from: 0,
        }
    }

    /// One tick: `counts` is the encoder's unwrapped count (since power-up while opening,
    /// since the rest once zeroed), `current_ua` the winding current (µA, nominal offset).
    pub fn step(&mut self, counts: i32, current_ua: i32) -> RestStep {
        self.ticks = self.ticks.saturating_add(1);
        match self.phase {
            Phase::Over => RestStep::Drive(0),
            Phase::Opening => self.opening(counts, current_ua),
            Phase::Returning => {
                if counts >= self.p.return_counts.saturating_neg() {
                    self.phase = Phase::Over;
                    return RestStep::Finished(RestReport {
                        power_up_counts: self.power_up_counts,
                        power_up_urad: 0,
                        stop_ticks: self.stop_ticks,
                        done_ticks: self.ticks,
                    });
                }
                if self.ticks.saturating_sub(self.return_from) > self.p.timeout_ticks {
                    return self.refuse(counts, true);
                }
                RestStep::Drive(self.p.return_duty)
            }
        }
    }

    fn opening(&mut self, counts: i32, current_ua: i32) -> RestStep {
        let travel = self.start_counts.saturating_sub(counts);
        if travel > self.p.max_travel_counts || self.ticks > self.p.timeout_ticks {
            return self.refuse(counts, false);
        }
        if counts.saturating_sub(self.anchor_counts).saturating_abs() > self.p.still_counts
            || current_ua.saturating_abs() < self.p.stall_ua_min
        {
            // Moving (or the motor is still turning against its back-EMF): a new window.
            self.anchor_counts = counts;
            self.anchor_tick = self.ticks;
        } else if self.ticks.saturating_sub(self.anchor_tick) >= self.p.still_ticks {
            // At the stop: this pose is stop_counts from the rest, so power-up was
            // (start − here) + stop_counts from it.
            self.power_up_counts = self
                .start_counts
                .saturating_sub(counts)
                .saturating_add(self.p.stop_counts);
            self.stop_ticks = self.ticks;
            self.return_from = self.ticks;
            self.phase = Phase::Returning;
            return RestStep::Zero {
                counts_from_rest: self.p.stop_counts,
                duty: self.p.return_duty,
            };
        }
        RestStep::Drive(self.p.open_duty.saturating_neg())
    }

    fn refuse(&mut self, counts: i32, returning: bool) -> RestStep {
        self.phase = Phase::Over;
        let moved = if returning {
            counts.saturating_sub(self.p.stop_counts)
        } else {
            counts.saturating_sub(self.start_counts)
        };
        RestStep::Refused(FaultReason::RestNotFound {
            moved_counts: moved,
            returning,
        })
    }

    /// The report once the check is over (`None` before, or when refused).
    pub fn report(&self) -> Option<RestReport> {
        (self.phase == Phase::Over && self.stop_ticks > 0).then_some(RestReport {
            power_up_counts: self.power_up_counts,
            power_up_urad: 0,
            stop_ticks: self.stop_ticks,
            done_ticks: self.ticks,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> RestParams {
        RestParams {
            open_duty: 800,
            return_duty: 500,
            stop_counts: -2500,
            still_counts: 3,
            still_ticks: 1000,
            timeout_ticks: 40_000,
            max_travel_counts: 80_000,
            return_counts: 60,
            stall_ua_min: 10_000,
        }
    }

    /// A stop at a fixed count: the state machine opens, finds it after `still_ticks`, zeroes
    /// it at `stop_counts` and reports the power-up pose (start − stop + stop_counts).
    #[test]
    fn finds_the_stop_and_reports_the_power_up_pose() {
        let start = 0;
        let stop_at = -3000; // the finger powered up 500 counts flexed
        let mut s = RestState::new(p(), start);
        let mut c = start;
        let mut zero_tick = None;
        for k in 1..20_000u32 {
            let ua = if c == stop_at { -25_000 } else { -2_000 };
            match s.step(c, ua) {
                RestStep::Drive(d) => {
                    assert_eq!(d, -800, "tick {k}");
                    c = (c - 2).max(stop_at);
                }
                RestStep::Zero {
                    counts_from_rest,
                    duty,
                } => {
                    assert_eq!((counts_from_rest, duty), (-2500, 500));
                    zero_tick = Some(k);
                    break;
                }
                other => panic!("{other:?} at {k}"),
            }
        }
        // 1500 ticks to travel 3000 counts, then 1000 still ticks.
        assert_eq!(zero_tick, Some(1500 + 1000));
        // Returning: counts now from the rest.
        let mut c = -2500;
        loop {
            match s.step(c, 5_000) {
                RestStep::Drive(d) => {
                    assert_eq!(d, 500);
                    c += 5;
                }
                RestStep::Finished(r) => {
                    assert_eq!(r.power_up_counts, 500);
                    assert!(c >= -60);
                    break;
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(s.report().map(|r| r.power_up_counts), Some(500));
    }

    /// A still encoder over a motor that still turns (little current: back-EMF) is not the
    /// stop; the check runs into its timeout and refuses with the bridge off.
    #[test]
    fn a_still_encoder_with_a_turning_motor_is_refused_at_the_timeout() {
        let mut s = RestState::new(p(), 100);
        for k in 1..=40_000u32 {
            assert_eq!(s.step(100, -2_000), RestStep::Drive(-800), "tick {k}");
        }
        assert_eq!(
            s.step(100, -2_000),
            RestStep::Refused(FaultReason::RestNotFound {
                moved_counts: 0,
                returning: false
            })
        );
        assert_eq!(s.step(100, 0), RestStep::Drive(0));
        assert_eq!(s.report(), None);
    }

    /// No stop within the finger's range: refused as soon as the travel exceeds it.
    #[test]
    fn no_stop_within_the_range_is_refused() {
        let mut s = RestState::new(p(), 0);
        let mut c = 0;
        let mut n = 0u32;
        let r = loop {
            n += 1;
            match s.step(c, -2_000) {
                RestStep::Drive(_) => c -= 10,
                other => break other,
            }
        };
        assert_eq!(
            r,
            RestStep::Refused(FaultReason::RestNotFound {
                moved_counts: -80_010,
                returning: false
            })
        );
        assert_eq!(n, 8002);
    }

    /// The paper settings on the default drive convert; bad values are refused.
    #[test]
    fn paper_settings_convert_and_bad_ones_are_refused() {
        let d = DriveConfig::DEFAULT;
        let q = RestCheck::PAPER.params(&d).unwrap();
        assert!(q.open_duty > 0 && q.open_duty < DUTY_MAX / 4, "{q:?}");
        assert!(q.stop_counts < 0);
        let mut b = RestCheck::PAPER;
        b.stop_from_rest_rad = 0.01;
        assert_eq!(b.params(&d), Err(ConfigError::OutOfRange));
        b = RestCheck::PAPER;
        b.open_torque_nm = f64::NAN;
        assert_eq!(b.params(&d), Err(ConfigError::NonFinite));
        b = RestCheck::PAPER;
        b.open_torque_nm = 100.0;
        assert_eq!(b.params(&d), Err(ConfigError::OutOfRange));
    }
}
