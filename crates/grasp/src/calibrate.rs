//! The calibration sweep on the board: a slow close-and-open of the free finger within a safe
//! torque and angle, bounded in time, that a host identifies the finger from (`pts
//! calibrate`). This module only generates the torque reference and decides which ticks to
//! record; the torque loop, the sensors and the log are the caller's. Integer only.
//!
//! Sequence: pause (reference 0) → closing (the reference rises at a fixed rate up to the safe
//! torque, or until θa reaches the angle limit) → opening (it falls at the same rate, below
//! zero if the gear does not back-drive, never below −safe torque, until θa is back near
//! rest) → pause → done. It refuses to start while a fault is latched and aborts (reference
//! 0) on a fault, on the angle limit being passed while opening, or on the time limit.
#![deny(clippy::float_arithmetic)]

/// The sweep's limits and pace. Angles are θa relative to the encoder zero (µrad), torques
/// at the crank (µN·m), times in control ticks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepConfig {
    /// Largest |reference| (µN·m), in [10 000, 1 500 000].
    pub safe_torque_unm: i32,
    /// Ticks for the reference to go from 0 to the safe torque, in [100, 10 000 000].
    pub ramp_ticks: u32,
    /// Ticks of reference 0 before and after the ramps, ≤ 1 000 000.
    pub pause_ticks: u32,
    /// θa beyond which the closing turns to opening (µrad), in [50 000, 3 000 000].
    pub max_dtheta_urad: i32,
    /// θa under which the opening ends (µrad), in [0, max_dtheta_urad / 2].
    pub end_dtheta_urad: i32,
    /// Ticks after which the sweep aborts, ≥ 2·pause + 3·ramp.
    pub timeout_ticks: u32,
    /// Record one tick in this many, in [1, 10 000].
    pub decimate: u16,
}

impl SweepConfig {
    /// 0.6 N·m in 8 s each way at 10 kHz, within 2.5 rad of θa, rows at 1 kHz.
    pub const DEFAULT: SweepConfig = SweepConfig {
        safe_torque_unm: 600_000,
        ramp_ticks: 80_000,
        pause_ticks: 5_000,
        max_dtheta_urad: 2_500_000,
        end_dtheta_urad: 30_000,
        timeout_ticks: 260_000,
        decimate: 10,
    };

    /// Checks every field; the error names it with the allowed range.
    pub fn validate(&self) -> Result<(), SweepError> {
        let chk = |field, v: i64, min: i64, max: i64| {
            if (min..=max).contains(&v) {
                Ok(())
            } else {
                Err(SweepError::BadConfig {
                    field,
                    value: v,
                    min,
                    max,
                })
            }
        };
        chk(
            "safe_torque_unm",
            i64::from(self.safe_torque_unm),
            10_000,
            1_500_000,
        )?;
        chk("ramp_ticks", i64::from(self.ramp_ticks), 100, 10_000_000)?;
        chk("pause_ticks", i64::from(self.pause_ticks), 0, 1_000_000)?;
        chk(
            "max_dtheta_urad",
            i64::from(self.max_dtheta_urad),
            50_000,
            3_000_000,
        )?;
        chk(
            "end_dtheta_urad",
            i64::from(self.end_dtheta_urad),
            0,
            i64::from(self.max_dtheta_urad) / 2,
        )?;
        let least = 2 * i64::from(self.pause_ticks) + 3 * i64::from(self.ramp_ticks);
        chk(
            "timeout_ticks",
            i64::from(self.timeout_ticks),
            least,
            i64::from(u32::MAX),
        )?;
        chk("decimate", i64::from(self.decimate), 1, 10_000)
    }
}

/// Why the sweep did not start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SweepError {
    /// A configuration field outside its range.
    BadConfig {
        /// Field name.
        field: &'static str,
        /// The value given.
        value: i64,
        /// Least allowed.
        min: i64,
        /// Largest allowed.
        max: i64,
    },
    /// A fault is latched: the finger must not move.
    FaultLatched,
    /// A sweep is already running.
    Busy,
}

/// Why a running sweep stopped early.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AbortReason {
    /// A fault was latched during the sweep.
    Fault,
    /// θa passed the angle limit by more than a tenth of it (the finger ran away).
    AngleLimit,
    /// The time limit passed.
    Timeout,
}

/// Where the sweep is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Not started.
    Idle,
    /// Reference 0 before closing.
    PauseBefore,
    /// Reference rising.
    Closing,
    /// Reference falling.
    Opening,
    /// Reference 0 after opening.
    PauseAfter,
    /// Finished: the record is complete.
    Done,
    /// Stopped early (reference 0).
    Aborted(AbortReason),
}

/// What one tick asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepStep {
    /// Torque reference for the torque loop (µN·m); 0 when idle, done or aborted.
    pub torque_ref_unm: i32,
    /// Record this tick (decimated, only while running).
    pub record: bool,
    /// Phase after this tick.
    pub phase: Phase,
}

/// The sweep's state machine. Its tick runs in the sampling task: no division (the rates
/// and limits are worked out once in [`Sweep::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sweep {
    cfg: SweepConfig,
    phase: Phase,
    ticks: u32,
    in_phase: u32,
    reference: i32,
    top: i32,
    /// Reference change per tick (µN·m ×2¹⁶).
    rate_q16: i64,
    /// θa beyond which the finger ran away (µrad): the angle limit and a tenth of it.
    runaway_urad: i64,
    /// Ticks until the next recorded one.
    until_record: u16,
}

impl Sweep {
    /// A sweep with a validated configuration.
    pub fn new(cfg: SweepConfig) -> Result<Sweep, SweepError> {
        cfg.validate()?;
        let max = i64::from(cfg.max_dtheta_urad);
        Ok(Sweep {
            cfg,
            phase: Phase::Idle,
            ticks: 0,
            in_phase: 0,
            reference: 0,
            top: 0,
            rate_q16: (i64::from(cfg.safe_torque_unm) << 16) / i64::from(cfg.ramp_ticks),
            runaway_urad: max + max / 10,
            until_record: cfg.decimate,
        })
    }

    /// The phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Starts the sweep with the finger at rest; refused while a fault is latched or a sweep
    /// runs.
    pub fn start(&mut self, fault_latched: bool) -> Result<(), SweepError> {
        if fault_latched {
            return Err(SweepError::FaultLatched);
        }
        if !matches!(self.phase, Phase::Idle | Phase::Done | Phase::Aborted(_)) {
            return Err(SweepError::Busy);
        }
        self.phase = Phase::PauseBefore;
        self.ticks = 0;
        self.in_phase = 0;
        self.reference = 0;
        self.until_record = self.cfg.decimate;
        Ok(())
    }

    /// The reference `n` ticks into a ramp (µN·m), limited to ±safe.
    fn ramp(&self, n: u32) -> i32 {
        let safe = i64::from(self.cfg.safe_torque_unm);
        ((self.rate_q16 * i64::from(n)) >> 16).min(safe).max(-safe) as i32
    }

    fn go(&mut self, phase: Phase) {
        self.phase = phase;
        self.in_phase = 0;
    }

    /// One control tick with θa relative to the encoder zero (µrad) and whether a fault is
    /// latched.
    pub fn tick(&mut self, dtheta_urad: i32, fault_latched: bool) -> SweepStep {
        let running = !matches!(self.phase, Phase::Idle | Phase::Done | Phase::Aborted(_));
        if running {
            self.ticks = self.ticks.saturating_add(1);
            self.in_phase = self.in_phase.saturating_add(1);
            let c = &self.cfg;
            let runaway = i64::from(dtheta_urad) > self.runaway_urad;
            if fault_latched {
                self.go(Phase::Aborted(AbortReason::Fault));
            } else if runaway {
                self.go(Phase::Aborted(AbortReason::AngleLimit));
            } else if self.ticks > c.timeout_ticks {
                self.go(Phase::Aborted(AbortReason::Timeout));
            } else {
                match self.phase {
                    Phase::PauseBefore if self.in_phase > c.pause_ticks => self.go(Phase::Closing),
                    Phase::Closing => {
                        self.reference = self.ramp(self.in_phase);
                        if self.reference >= c.safe_torque_unm || dtheta_urad >= c.max_dtheta_urad {
                            self.top = self.reference;
                            self.go(Phase::Opening);
                        }
                    }
                    Phase::Opening => {
                        // Down from the top at the ramp's rate, never below −safe; held there
                        // until the finger is back (or the time limit).
                        let down = (self.rate_q16 * i64::from(self.in_phase)) >> 16;
                        self.reference =
                            (i64::from(self.top) - down).max(-i64::from(c.safe_torque_unm)) as i32;
                        if dtheta_urad <= c.end_dtheta_urad {
                            self.go(Phase::PauseAfter);
                        }
                    }
                    Phase::PauseAfter if self.in_phase > c.pause_ticks => self.go(Phase::Done),
                    _ => {}
                }
            }
        }
        if !matches!(self.phase, Phase::Closing | Phase::Opening) {
            self.reference = 0;
        }
        let running = !matches!(self.phase, Phase::Idle | Phase::Done | Phase::Aborted(_));
        let mut record = false;
        if running {
            self.until_record = self.until_record.saturating_sub(1);
            if self.until_record == 0 {
                record = true;
                self.until_record = self.cfg.decimate;
            }
        }
        SweepStep {
            torque_ref_unm: self.reference,
            record,
            phase: self.phase,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(
        cfg: SweepConfig,
        theta: impl Fn(i32) -> i32,
        fault_at: Option<u32>,
    ) -> (Phase, i32, i32, u32) {
        let mut s = Sweep::new(cfg).unwrap();
        s.start(false).unwrap();
        let (mut max_ref, mut min_ref) = (0, 0);
        let mut last = 0;
        let mut n = 0;
        while !matches!(s.phase(), Phase::Done | Phase::Aborted(_)) && n < 10_000_000 {
            n += 1;
            let st = s.tick(theta(last), fault_at.is_some_and(|f| n >= f));
            last = st.torque_ref_unm;
            max_ref = max_ref.max(last);
            min_ref = min_ref.min(last);
        }
        (s.phase(), max_ref, min_ref, n)
    }

    const SMALL: SweepConfig = SweepConfig {
        safe_torque_unm: 100_000,
        ramp_ticks: 1_000,
        pause_ticks: 100,
        max_dtheta_urad: 500_000,
        end_dtheta_urad: 10_000,
        timeout_ticks: 5_000,
        decimate: 10,
    };

    #[test]
    fn a_finger_that_follows_the_torque_is_swept_within_the_safe_torque() {
        // A spring finger: θa = 4 µrad per µN·m of reference.
        let (phase, max_ref, min_ref, n) = run(SMALL, |r| 4 * r, None);
        assert_eq!(phase, Phase::Done);
        assert_eq!(max_ref, SMALL.safe_torque_unm);
        assert!(min_ref >= -SMALL.safe_torque_unm);
        assert!(n <= SMALL.timeout_ticks, "{n}");
    }

    #[test]
    fn the_angle_limit_turns_the_closing_round() {
        // A soft finger that reaches the angle limit at a fifth of the safe torque.
        let (phase, max_ref, _, _) = run(SMALL, |r| 25 * r, None);
        assert_eq!(phase, Phase::Done);
        assert!(max_ref * 25 >= SMALL.max_dtheta_urad && max_ref < SMALL.safe_torque_unm / 4);
    }

    #[test]
    fn a_finger_that_never_opens_times_out_with_the_reference_at_zero() {
        let (phase, _, min_ref, n) = run(SMALL, |_| 200_000, None);
        assert_eq!(phase, Phase::Aborted(AbortReason::Timeout));
        assert_eq!(min_ref, -SMALL.safe_torque_unm);
        assert_eq!(n, SMALL.timeout_ticks + 1);
    }

    #[test]
    fn a_fault_aborts_and_a_latched_fault_refuses_the_start() {
        let (phase, _, _, n) = run(SMALL, |r| 4 * r, Some(700));
        assert_eq!(phase, Phase::Aborted(AbortReason::Fault));
        assert_eq!(n, 700);
        let mut s = Sweep::new(SMALL).unwrap();
        assert_eq!(s.start(true), Err(SweepError::FaultLatched));
        let st = s.tick(0, false);
        assert_eq!((st.torque_ref_unm, st.record), (0, false));
    }

    #[test]
    fn bad_configurations_name_the_field() {
        let e = Sweep::new(SweepConfig {
            safe_torque_unm: 2_000_000,
            ..SMALL
        });
        assert!(matches!(
            e,
            Err(SweepError::BadConfig {
                field: "safe_torque_unm",
                ..
            })
        ));
        let e = Sweep::new(SweepConfig {
            timeout_ticks: 10,
            ..SMALL
        });
        assert!(matches!(
            e,
            Err(SweepError::BadConfig {
                field: "timeout_ticks",
                ..
            })
        ));
    }
}
