//! The fast half of the controller: one [`ControlLoop::tick`] per control period (10 kHz).
//!
//! It reads the sensors, checks what must be caught within a tick (encoder jump, ADC code,
//! ADC at a rail, over-current, stall), moves the torque reference as the [`Setpoint`] says, runs the
//! torque loop and sums θa, T_a, duty and current over `sample_ticks` ticks. A finished sum
//! goes to the [`Supervisor`](crate::Supervisor) through the [`Link`]; the supervisor (the
//! grasp state machine, a lower priority on the target) answers with the next [`Setpoint`].
//!
//! Why the split: the state machine's work comes in bursts (contact detection scans the
//! history, seating and settling average windows) of several thousand instructions once per
//! sample; the loop's own work is a few hundred instructions every tick with no division.
//! Run together, the burst set the sampling task's worst case; split, the sampling task is
//! short and constant and the burst runs preemptibly below it.
//!
//! Supervision: every setpoint carries the supervisor's stamp (the newest loop tick it has
//! acted on). The loop drives only while that stamp is at most [`ControlLoop::max_setpoint_age_ticks`]
//! old (`LINK_SAMPLES` samples, what the link can hold: 16 ms at 10 kHz and 4 ms samples); an
//! older one trips the loop with [`FaultReason::SupervisorStalled`], bridge off, latched. A
//! stalled supervisor therefore cannot leave the motor pushing on its last setpoint.
//!
//! Everything here is bounded integer arithmetic: the inputs are clamped where they enter
//! (the parameters to i32 by [`ControllerConfig::params`](crate::ControllerConfig::params),
//! the sums over at most 64 ticks of i32 values), so the products are single 32×32→64
//! multiplies and no saturating 64-bit multiply is needed.
#![deny(clippy::float_arithmetic)]

use crate::calibrate::{AbortReason, Phase as SweepPhase, Sweep};
use crate::config::Params;
use crate::rest::{RestReport, RestState, RestStep};
use crate::sensors::{sat_i32, CurrentSense, Encoder};
use crate::state::{FaultReason, State};
use crate::torque_loop::TorqueLoop;
use crate::{Hardware, DUTY_MAX};

/// Finished sample sums the link holds; when it is full new ones are dropped and counted (the
/// supervisor empties it every sample; 4 give 4 samples of slack). A power of two.
pub const LINK_SAMPLES: usize = 4;
const _: () = assert!(LINK_SAMPLES.is_power_of_two() && LINK_SAMPLES < 128);

/// A torque (µN·m ×2¹⁶) limited to ±2⁴⁶ (±1 073 N·m) when it is made, so the loop can add
/// and compare references without saturating arithmetic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TorqueQ16(i64);

impl TorqueQ16 {
    /// Largest magnitude (µN·m ×2¹⁶).
    pub const LIMIT: i64 = 1 << 46;

    /// From µN·m ×2¹⁶, limited to ±[`TorqueQ16::LIMIT`].
    pub const fn new(v: i64) -> Self {
        Self(if v > Self::LIMIT {
            Self::LIMIT
        } else if v < -Self::LIMIT {
            -Self::LIMIT
        } else {
            v
        })
    }

    /// From µN·m.
    pub const fn from_unm(unm: i32) -> Self {
        Self((unm as i64) << 16)
    }

    /// The value (µN·m ×2¹⁶).
    pub const fn get(self) -> i64 {
        self.0
    }
}

/// How the torque reference moves this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reference {
    /// Stays where it is.
    Hold,
    /// Moves toward `target` by at most `rate` per tick.
    Ramp {
        /// Target.
        target: TorqueQ16,
        /// Largest change per tick (negative acts as zero).
        rate: TorqueQ16,
    },
    /// Jumps to this value.
    Set(TorqueQ16),
}

/// What the supervisor asks of the loop until it says otherwise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    /// Bridge enabled and torque loop running; `false` is the safe state (bridge off,
    /// reference and integrator cleared).
    pub enable: bool,
    /// The torque reference's motion.
    pub reference: Reference,
    /// Virtual damping B·ω̂a subtracted from the reference (µN·m), from the supervisor's
    /// speed estimate.
    pub damp_unm: i32,
}

impl Setpoint {
    /// Bridge off.
    pub const OFF: Setpoint = Setpoint {
        enable: false,
        reference: Reference::Hold,
        damp_unm: 0,
    };
}

/// Sums of one sample interval, as the loop hands them over (no division in the loop).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SampleSums {
    /// Tick at the end of the interval.
    pub tick: u32,
    /// Ticks summed (`sample_ticks`).
    pub n: u32,
    /// Σ θa (µrad), each tick's θa limited to ±2²⁴ µrad (±16.7 rad, beyond any pose).
    pub theta_urad: i32,
    /// Σ measured T_a (µN·m), each tick's limited to ±2²⁴ µN·m (±16.7 N·m, beyond the drive).
    pub torque_unm: i32,
    /// Σ duty applied over the interval (the duty of the previous tick, as the bridge held it).
    pub duty: i32,
    /// Σ motor current (µA), each tick's limited to ±2²⁴ µA (±16.7 A, beyond the drive).
    pub ua: i32,
    /// Encoder counts since rest at the end of the interval.
    pub counts: i32,
    /// Torque reference at the end of the interval (µN·m).
    pub torque_ref_unm: i32,
}

impl SampleSums {
    /// All zero.
    pub const ZERO: SampleSums = SampleSums {
        tick: 0,
        n: 0,
        theta_urad: 0,
        torque_unm: 0,
        duty: 0,
        ua: 0,
        counts: 0,
        torque_ref_unm: 0,
    };
}

/// The two halves' mailbox: the setpoint one way, sums and the loop's own news the other.
/// On the target it is one RTIC resource; every access is a copy of a few words.
#[derive(Clone, Debug)]
pub struct Link {
    /// What the loop applies from its next tick (written by the supervisor).
    pub setpoint: Setpoint,
    /// The supervisor's state, published for the sampling task (telemetry, end of run).
    pub state: State,
    /// A small ring (power-of-two capacity: the index is a mask, the push a few
    /// instructions; heapless' Deque cost the sampling task ~40 more per sample).
    samples: [SampleSums; LINK_SAMPLES],
    head: u8,
    len: u8,
    samples_dropped: u32,
    started: bool,
    calibrated: Option<(u32, i32)>,
    fault: Option<(u32, FaultReason)>,
    /// The supervisor's heartbeat: the newest loop tick it has acted on.
    stamp_tick: u32,
}

/// What the loop hands the supervisor, in the order [`Link::next_input`] gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Input {
    /// The loop took its first reading (θa at rest) and is calibrating the current offset.
    Started,
    /// Calibration done: the loop drives as soon as the setpoint enables it.
    Calibrated {
        /// Tick.
        tick: u32,
        /// Zero-current ADC code ×256.
        offset_q8: i32,
    },
    /// A finished sample.
    Sample(SampleSums),
    /// The loop's own fault (bridge already off).
    LoopFault {
        /// Tick.
        tick: u32,
        /// Why.
        reason: FaultReason,
    },
}

impl Default for Link {
    fn default() -> Self {
        Self::new()
    }
}

impl Link {
    /// Empty, bridge off.
    pub const fn new() -> Self {
        Self {
            setpoint: Setpoint::OFF,
            state: State::Init,
            samples: [SampleSums::ZERO; LINK_SAMPLES],
            head: 0,
            len: 0,
            samples_dropped: 0,
            started: false,
            calibrated: None,
            fault: None,
            stamp_tick: 0,
        }
    }

    /// Stamps the setpoint with the newest loop tick the supervisor has acted on
    /// ([`Supervisor::publish`](crate::Supervisor::publish) does it; the loop refuses to
    /// drive on a stamp older than [`ControlLoop::max_setpoint_age_ticks`]).
    pub fn stamp(&mut self, tick: u32) {
        self.stamp_tick = tick;
    }

    /// The supervisor's last stamp (loop ticks).
    pub fn stamp_tick(&self) -> u32 {
        self.stamp_tick
    }

    /// Whether [`Link::next_input`] has something.
    pub fn has_input(&self) -> bool {
        self.started || self.calibrated.is_some() || self.len > 0 || self.fault.is_some()
    }

    /// The next input for the supervisor: start, calibration, samples oldest first, and the
    /// loop's fault after the samples that preceded it. Each latched item is given once.
    pub fn next_input(&mut self) -> Option<Input> {
        if core::mem::take(&mut self.started) {
            return Some(Input::Started);
        }
        if let Some((tick, offset_q8)) = self.calibrated.take() {
            return Some(Input::Calibrated { tick, offset_q8 });
        }
        if self.len > 0 {
            let s = self.samples[usize::from(self.head) & (LINK_SAMPLES - 1)];
            self.head = self.head.wrapping_add(1);
            self.len -= 1;
            return Some(Input::Sample(s));
        }
        self.fault
            .take()
            .map(|(tick, reason)| Input::LoopFault { tick, reason })
    }

    /// Samples the loop could not hand over (link full).
    pub fn samples_dropped(&self) -> u32 {
        self.samples_dropped
    }

    fn push_sample(&mut self, s: SampleSums) {
        if usize::from(self.len) >= LINK_SAMPLES {
            self.samples_dropped = self.samples_dropped.saturating_add(1);
            return;
        }
        self.samples[usize::from(self.head.wrapping_add(self.len)) & (LINK_SAMPLES - 1)] = s;
        self.len += 1;
    }
}

/// What one loop tick measured and did (for telemetry).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoopOutput {
    /// The tick number.
    pub tick: u32,
    /// θa (µrad), absolute model angle.
    pub theta_a_urad: i32,
    /// Measured T_a (µN·m), one sample.
    pub torque_unm: i32,
    /// Torque reference (µN·m); 0 with the bridge off.
    pub torque_ref_unm: i32,
    /// Duty applied (±DUTY_MAX), 0 with the bridge off.
    pub duty: i16,
    /// A finished sample went into the link this tick: run the supervisor.
    pub sample_ready: bool,
    /// The loop switched the bridge off this tick (its own fault, the setpoint, or the end
    /// of a calibration sweep).
    pub went_off: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Init,
    /// The rest check: finding the open stop, zeroing there, back to rest.
    Homing,
    Calibrating,
    Running,
    /// The calibration sweep drives the torque reference (no supervisor).
    Sweeping,
    /// The sweep is over (done or aborted): bridge off for good.
    SweepOver,
    /// The loop's own fault: latched, bridge off for good.
    Tripped,
}

/// Sums over one sample interval: at most 64 ticks (the configuration's limit) of values
/// limited to ±2²⁴, so i32 sums cannot overflow. (The tick count is kept beside them: four
/// words clear in two stores, five took a library call.)
#[derive(Clone, Copy, Debug, Default)]
struct Acc {
    theta: i32,
    torque: i32,
    duty: i32,
    ua: i32,
}

/// Encoder counts the motor must turn while the duty is saturated for it not to be a stall
/// (a few counts of quantisation and gear play).
const STALL_COUNTS: u32 = 8;

/// Limits a per-tick value to ±2²⁴ before it is summed (one instruction on Cortex-M4).
#[inline(always)]
fn lim24(v: i32) -> i32 {
    v.clamp(-(1 << 24), (1 << 24) - 1)
}

/// The control loop's state. Integer only, no division, bounded time.
#[derive(Clone, Debug)]
pub struct ControlLoop {
    p: Params,
    phase: Phase,
    tick: u32,
    enc: Encoder,
    cur: CurrentSense,
    tl: TorqueLoop,
    /// Torque reference, µN·m ×2¹⁶.
    t_ref_q16: i64,
    /// Whether the bridge is being driven (last setpoint enabled).
    driving: bool,
    acc: Acc,
    /// Ticks summed in `acc`.
    acc_n: u32,
    oc_count: u32,
    /// Consecutive driving ticks with the ADC at a rail.
    rail_count: u32,
    stall_count: u32,
    last_duty: i16,
    /// Oldest supervisor stamp the loop drives on (ticks).
    max_age_ticks: u32,
    /// Per-configuration limits the tick compares with, worked out once: ticks per sample
    /// (`sample_ticks`, at most 64), the over-current count's trip level (2 per tick
    /// over `overcurrent_ticks`) and |the over-current limit| (µA).
    sample_n: u32,
    oc_trip: u32,
    oc_ua: u32,
    /// The rest check (configured: `Some` from the first tick until the loop runs).
    rest: Option<RestState>,
    /// What the rest check found (once it is over).
    rest_report: Option<RestReport>,
    /// Tick the current calibration started after (0, or the end of the rest check).
    calib_from: u32,
    /// The calibration sweep that replaces the supervisor's setpoints ([`ControlLoop::for_sweep`]).
    sweep: Option<Sweep>,
    /// Encoder count where the sweep's duty last started saturating.
    stall_from_counts: i32,
    /// The sweep's last tick is one to record (kept out of [`LoopOutput`]: a larger
    /// output costs the grasp's every tick).
    sweep_record: bool,
}

impl ControlLoop {
    /// A loop before its first tick (bridge off; the first reading is θa at rest).
    pub fn new(p: &Params) -> Self {
        let p = *p;
        Self {
            p,
            phase: Phase::Init,
            tick: 0,
            enc: Encoder::new(0),
            cur: CurrentSense::new(&p),
            tl: TorqueLoop::new(),
            t_ref_q16: 0,
            driving: false,
            acc: Acc::default(),
            acc_n: 0,
            oc_count: 0,
            rail_count: 0,
            stall_count: 0,
            last_duty: 0,
            max_age_ticks: LINK_SAMPLES as u32 * p.sample_ticks.clamp(1, 64),
            sample_n: p.sample_ticks.min(64),
            oc_trip: p.overcurrent_ticks.saturating_mul(2),
            oc_ua: p.overcurrent_ua.unsigned_abs(),
            rest: None,
            rest_report: None,
            calib_from: 0,
            sweep: None,
            stall_from_counts: 0,
            sweep_record: false,
        }
    }

    /// A loop that runs a calibration sweep instead of a grasp: the same sensors, current
    /// calibration (and rest check, when configured), fast faults and torque loop, with the
    /// sweep's reference in place of the supervisor's setpoints. It tells the supervisor
    /// nothing but its own faults, and stops for good (bridge off) when the sweep ends.
    pub fn for_sweep(p: &Params, sweep: Sweep) -> Self {
        let mut lp = Self::new(p);
        lp.sweep = Some(sweep);
        lp
    }

    /// Whether the sweep's last tick is a row to record (one in the sweep's decimation; its
    /// values are that tick's [`LoopOutput`] and raw readings).
    pub fn sweep_record(&self) -> bool {
        self.sweep_record
    }

    /// Where the sweep of a [`ControlLoop::for_sweep`] loop is (`None` for a grasp loop); a
    /// loop fault reads as [`AbortReason::Fault`].
    pub fn sweep_phase(&self) -> Option<SweepPhase> {
        let sweep = self.sweep.as_ref()?;
        Some(match (self.phase, sweep.phase()) {
            (Phase::Tripped, _) => SweepPhase::Aborted(AbortReason::Fault),
            (Phase::SweepOver, p @ (SweepPhase::Done | SweepPhase::Aborted(_))) => p,
            // Over without the sweep having run (it could not start): not a calibration.
            (Phase::SweepOver, _) => SweepPhase::Aborted(AbortReason::Fault),
            (_, p) => p,
        })
    }

    /// What the rest check found: θa at power-up relative to the rest and its times
    /// (`None` before it ends, when it refused, or when none is configured).
    pub fn rest_report(&self) -> Option<RestReport> {
        // The report of a finished check; `Finished` fills in the µrad.
        self.rest_report
    }

    /// The oldest supervisor stamp the loop still drives on: `LINK_SAMPLES` samples, the
    /// most the link holds for the supervisor (16 ms with 4 ms samples at 10 kHz).
    pub fn max_setpoint_age_ticks(&self) -> u32 {
        self.max_age_ticks
    }

    /// Ticks since the supervisor last stamped the link.
    pub fn setpoint_age_ticks(&self, link: &Link) -> u32 {
        self.tick.wrapping_sub(link.stamp_tick)
    }

    /// Ticks since start.
    pub fn ticks(&self) -> u32 {
        self.tick
    }

    /// Torque reference (µN·m).
    pub fn torque_ref_unm(&self) -> i32 {
        sat_i32(self.t_ref_q16 >> 16)
    }

    /// Whether the loop is driving the bridge (its last tick had an enabled setpoint).
    pub fn driving(&self) -> bool {
        self.driving
    }

    /// Bridge off now, reference and integrator cleared (the setpoint still decides
    /// whether the next tick drives again).
    pub fn stop<H: Hardware + ?Sized>(&mut self, hw: &mut H) {
        hw.bridge_off();
        self.tl.reset();
        self.t_ref_q16 = 0;
        self.last_duty = 0;
        self.acc = Acc::default();
        self.acc_n = 0;
        self.driving = false;
    }

    /// One saturated tick of the stall count: true once the duty has been at its limit for
    /// the stall time with the motor not turning (counted from where the saturation began).
    /// Out of line: only saturated ticks pay for it.
    #[inline(never)]
    fn stalled(&mut self) -> bool {
        let counts = self.enc.counts();
        if self.stall_count == 0 {
            self.stall_from_counts = counts;
        }
        let moved = counts.wrapping_sub(self.stall_from_counts).unsigned_abs() > STALL_COUNTS;
        self.stall_count = if moved {
            0
        } else {
            self.stall_count.saturating_add(1)
        };
        self.stall_count >= self.p.stall_ticks
    }

    fn trip<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        link: &mut Link,
        reason: FaultReason,
        out: &mut LoopOutput,
    ) {
        self.stop(hw);
        self.phase = Phase::Tripped;
        if link.fault.is_none() {
            link.fault = Some((self.tick, reason));
        }
        out.went_off = true;
    }

    /// The interval's sums into the link, and a new interval (one tick in `sample_n`).
    #[inline(always)]
    fn finish_sample(&mut self, link: &mut Link, t_ref: i32) {
        link.push_sample(SampleSums {
            tick: self.tick,
            n: self.acc_n,
            theta_urad: self.acc.theta,
            torque_unm: self.acc.torque,
            duty: self.acc.duty,
            ua: self.acc.ua,
            counts: self.enc.counts(),
            torque_ref_unm: t_ref,
        });
        self.acc = Acc::default();
        self.acc_n = 0;
    }

    /// The encoder and ADC readings checked and converted: (θa µrad, T_a µN·m), also put in
    /// `out`; `None` after tripping on a jump or an impossible code.
    #[inline(always)]
    fn read_sensors<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        link: &mut Link,
        raw_enc: u16,
        code: u16,
        out: &mut LoopOutput,
    ) -> Option<(i32, i32)> {
        if let Err(j) = self.enc.update(raw_enc, self.p.encoder_max_step) {
            let reason = FaultReason::EncoderJump {
                step_counts: j.step_counts,
            };
            self.trip(hw, link, reason, out);
            return None;
        }
        let theta = self.enc.theta_a_urad(&self.p);
        if code > 4095 {
            self.trip(hw, link, FaultReason::AdcCode { code }, out);
            return None;
        }
        let torque = self.cur.torque_unm(code, &self.p);
        out.theta_a_urad = theta;
        out.torque_unm = torque;
        Some((theta, torque))
    }

    /// A tick before the loop drives: tripped (bridge off), the first tick, the rest check or
    /// the current calibration.
    #[inline(never)]
    fn before_running<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        link: &mut Link,
        raw_enc: u16,
        code: u16,
        out: &mut LoopOutput,
    ) {
        match self.phase {
            Phase::Tripped | Phase::SweepOver => {
                hw.bridge_off();
                return;
            }
            Phase::Init => {
                // First tick. Without a rest check the finger is taken to be at rest and the
                // reading there is θa,rest; with one, the count runs from here until the
                // check zeroes it at the open stop.
                hw.bridge_off();
                self.enc = Encoder::new(raw_enc);
                self.phase = Phase::Calibrating;
                if let Some(rp) = self.p.rest {
                    self.rest = Some(RestState::new(rp, 0));
                    self.phase = Phase::Homing;
                }
                // A sweep has no supervisor to start.
                link.started = self.sweep.is_none();
            }
            _ => {}
        }
        if self.read_sensors(hw, link, raw_enc, code, out).is_none() {
            return;
        }
        if self.phase == Phase::Homing {
            self.homing(hw, link, code, out);
            return;
        }
        if self.phase == Phase::Sweeping {
            self.sweeping(hw, link, code, out);
            return;
        }
        self.cur.calib_add(code);
        if self.tick.wrapping_sub(self.calib_from) >= self.p.calib_ticks {
            match self.cur.calib_finish(&self.p) {
                Ok(offset_q8) => match self.sweep.as_mut().map(|sw| sw.start(false)) {
                    // A validated sweep that is not running always starts.
                    Some(Ok(())) => self.phase = Phase::Sweeping,
                    Some(Err(_)) => self.phase = Phase::SweepOver,
                    None => {
                        self.phase = Phase::Running;
                        link.calibrated = Some((self.tick, offset_q8));
                    }
                },
                Err(offset_q8) => self.trip(hw, link, FaultReason::AdcOffset { offset_q8 }, out),
            }
        }
    }

    /// The current faults of a driving tick: an ADC pinned at a rail, or over-current.
    /// Inlined: the sampling task's path must not pay a call for it.
    #[inline(always)]
    fn current_fault(&mut self, code: u16, ua: i32) -> Option<FaultReason> {
        // An ADC pinned at a rail reads nothing: the current may be anywhere beyond it.
        // Over the over-current time it is a fault of its own (the configuration keeps the
        // limit inside the sensor's range, so a healthy drive trips over-current first).
        // code 0 or 4095 (4096… were refused as AdcCode): one unsigned compare.
        if code.wrapping_sub(1) >= 4094 {
            self.rail_count += 1;
            if self.rail_count >= self.p.overcurrent_ticks {
                return Some(FaultReason::AdcRail { code });
            }
        } else {
            self.rail_count = 0;
        }
        // Over-current on the raw sample, with a leaky count (+2 above the limit, −1 below)
        // so a current chattering around the limit still trips: it trips after
        // `overcurrent_ticks` ticks above it in a row, or later whenever more than a third of
        // the ticks are above it.
        if ua.unsigned_abs() > self.oc_ua {
            self.oc_count = self.oc_count.saturating_add(2);
            if self.oc_count >= self.oc_trip {
                return Some(FaultReason::OverCurrent { current_ua: ua });
            }
        } else {
            self.oc_count = self.oc_count.saturating_sub(1);
        }
        None
    }

    /// One tick of the calibration sweep: the fast faults as in a grasp, the sweep's
    /// reference through the torque loop, the bridge off for good when it ends.
    fn sweeping<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        link: &mut Link,
        code: u16,
        out: &mut LoopOutput,
    ) {
        self.sweep_record = false;
        let ua = self.cur.current_ua(code, &self.p);
        if let Some(reason) = self.current_fault(code, ua) {
            self.trip(hw, link, reason, out);
            return;
        }
        let dtheta_urad =
            sat_i32((i64::from(self.enc.counts()) * i64::from(self.p.urad_per_count_q16)) >> 16);
        let Some(st) = self.sweep.as_mut().map(|sw| sw.tick(dtheta_urad, false)) else {
            return;
        };
        self.sweep_record = st.record;
        if matches!(st.phase, SweepPhase::Done | SweepPhase::Aborted(_)) {
            self.stop(hw);
            self.phase = Phase::SweepOver;
            out.went_off = true;
            return;
        }
        let duty = self.tl.update(st.torque_ref_unm, out.torque_unm, &self.p);
        // The free finger springing back open saturates the duty through its back-EMF while
        // it moves: not a stall ([`ControlLoop::stalled`]).
        if self.tl.saturated() {
            if self.stalled() {
                self.trip(hw, link, FaultReason::Stall, out);
                return;
            }
        } else {
            self.stall_count = 0;
        }
        let duty = duty.clamp(-DUTY_MAX, DUTY_MAX);
        hw.set_duty(duty);
        self.driving = true;
        self.last_duty = duty;
        out.duty = duty;
        out.torque_ref_unm = st.torque_ref_unm;
    }

    /// One tick of the rest check: its duty, the encoder re-zeroed at the stop, the bridge off
    /// when it is over (then the current calibration starts) or refused (tripped).
    fn homing<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        link: &mut Link,
        code: u16,
        out: &mut LoopOutput,
    ) {
        if self.rest.is_none() {
            self.phase = Phase::Calibrating;
            hw.bridge_off();
            return;
        }
        // Nominal zero code (not yet calibrated): enough to tell stall current from none.
        let ua = self.cur.current_ua(code, &self.p);
        // The check drives too: a shorted winding or a pinned ADC trips as in the grasp
        // (its duty bounds the torque only while the winding is sound).
        if let Some(reason) = self.current_fault(code, ua) {
            self.rest = None;
            self.trip(hw, link, reason, out);
            return;
        }
        let Some(rest) = self.rest.as_mut() else {
            return;
        };
        match rest.step(self.enc.counts(), ua) {
            RestStep::Drive(d) => hw.set_duty(d.clamp(-DUTY_MAX, DUTY_MAX)),
            RestStep::Zero {
                counts_from_rest,
                duty,
            } => {
                self.enc.set_counts(counts_from_rest);
                out.theta_a_urad = self.enc.theta_a_urad(&self.p);
                hw.set_duty(duty.clamp(-DUTY_MAX, DUTY_MAX));
            }
            RestStep::Finished(mut r) => {
                hw.bridge_off();
                let rel =
                    (i64::from(r.power_up_counts) * i64::from(self.p.urad_per_count_q16)) >> 16;
                r.power_up_urad = sat_i32(rel);
                self.rest_report = Some(r);
                self.rest = None;
                self.calib_from = self.tick;
                self.phase = Phase::Calibrating;
            }
            RestStep::Refused(reason) => {
                self.rest = None;
                self.trip(hw, link, reason, out);
            }
        }
    }

    /// One control period: sensors, fast supervision, reference, torque loop, sums.
    pub fn tick<H: Hardware + ?Sized>(&mut self, hw: &mut H, link: &mut Link) -> LoopOutput {
        self.tick = self.tick.wrapping_add(1);
        let raw_enc = hw.encoder_count();
        let code = hw.current_raw();
        let mut out = LoopOutput {
            tick: self.tick,
            ..LoopOutput::default()
        };
        // One compare on the driving path; the other phases out of line.
        if self.phase != Phase::Running {
            self.before_running(hw, link, raw_enc, code, &mut out);
            return out;
        }
        let Some((theta, torque)) = self.read_sensors(hw, link, raw_enc, code, &mut out) else {
            return out;
        };

        let sp = link.setpoint;
        if !sp.enable {
            if self.driving {
                out.went_off = true;
            }
            self.stop(hw);
            return out;
        }
        // The supervisor's heartbeat: never drive on a setpoint it no longer vouches for.
        let age_ticks = self.tick.wrapping_sub(link.stamp_tick);
        if age_ticks > self.max_age_ticks {
            let reason = FaultReason::SupervisorStalled { age_ticks };
            self.trip(hw, link, reason, &mut out);
            return out;
        }
        self.driving = true;

        let ua = self.cur.current_ua(code, &self.p);
        if let Some(reason) = self.current_fault(code, ua) {
            self.trip(hw, link, reason, &mut out);
            return out;
        }

        // All three within ±2⁴⁶ (TorqueQ16): plain arithmetic cannot overflow.
        self.t_ref_q16 = match sp.reference {
            Reference::Hold => self.t_ref_q16,
            Reference::Set(v) => v.get(),
            Reference::Ramp { target, rate } => {
                let r = rate.get().max(0);
                self.t_ref_q16 + (target.get() - self.t_ref_q16).max(-r).min(r)
            }
        };
        let t_ref = (self.t_ref_q16 >> 16) as i32;

        // Sums over the sample interval (see `Acc`). A hand-made `Params` with more than 64
        // ticks per sample is cut at 64 so the sums stay exact.
        self.acc.theta += lim24(theta);
        self.acc.torque += lim24(torque);
        self.acc.duty += i32::from(self.last_duty);
        self.acc.ua += lim24(ua);
        self.acc_n += 1;
        if self.acc_n >= self.sample_n {
            self.finish_sample(link, t_ref);
            out.sample_ready = true;
        }

        // Torque loop on T_cmd = T_ref − B·ω̂a.
        let t_cmd = t_ref.saturating_sub(sp.damp_unm);
        let duty = self.tl.update(t_cmd, torque, &self.p);
        // A stall is the duty at its limit with the motor not turning (counted from where the
        // saturation began): a fast step on a soft contact holds the duty at its limit
        // through the back-EMF while the finger travels, and that is not a stall.
        if self.tl.saturated() {
            if self.stalled() {
                self.trip(hw, link, FaultReason::Stall, &mut out);
                return out;
            }
        } else {
            self.stall_count = 0;
        }
        let duty = duty.clamp(-DUTY_MAX, DUTY_MAX);
        hw.set_duty(duty);
        self.last_duty = duty;
        out.duty = duty;
        out.torque_ref_unm = t_ref;
        out
    }
}
