//! The calibration sweep as the firmware runs it: [`ControlLoop::for_sweep`] on a quasi-static
//! spring finger (no plant, no supervisor), against the sweep's own limits.
use grasp::calibrate::{AbortReason, Phase, SweepConfig};
use grasp::{ControlLoop, ControllerConfig, FaultReason, Hardware, Input, Link, DUTY_MAX};

/// A free finger that follows its spring: θa moves toward rest + T_a / k (rad) by at most
/// 20 counts a tick; the current is what the duty drives through the winding (no back-EMF).
struct Spring {
    d: grasp::DriveConfig,
    k_nm_per_rad: f64,
    duty: f64,
    off: bool,
    /// Extra current the ADC reports (A): a shorted winding.
    leak_a: f64,
    /// No current flows whatever the duty (a broken wire): the motor neither turns nor reads.
    open_winding: bool,
    /// Ticks after which the encoder runs away (a finger that does not stop).
    runaway_after: Option<u32>,
    ticks: u32,
    counts: f64,
}

impl Spring {
    fn new(k_nm_per_rad: f64) -> Self {
        Spring {
            d: ControllerConfig::DEFAULT.drive,
            k_nm_per_rad,
            duty: 0.0,
            off: true,
            leak_a: 0.0,
            open_winding: false,
            runaway_after: None,
            ticks: 0,
            counts: 0.0,
        }
    }
    fn amps(&self) -> f64 {
        let a = if self.off || self.open_winding {
            0.0
        } else {
            self.duty * self.d.bus_v / self.d.resistance_ohm
        };
        a + self.leak_a
    }
    fn theta_rel_rad(&self) -> f64 {
        let run = self
            .runaway_after
            .map_or(0.0, |t| f64::from(self.ticks.saturating_sub(t)) * 1e-3);
        self.amps() * self.d.torque_per_amp() / self.k_nm_per_rad + run
    }
}

impl Hardware for Spring {
    fn encoder_count(&mut self) -> u16 {
        self.ticks += 1;
        let target = self.theta_rel_rad() / self.d.rad_per_count();
        self.counts += (target - self.counts).clamp(-20.0, 20.0);
        (self.counts.round() as i64 + 1000) as u16
    }
    fn current_raw(&mut self) -> u16 {
        (self.d.adc_zero_code + self.amps() / self.d.amps_per_code)
            .round()
            .clamp(0.0, 4095.0) as u16
    }
    fn set_duty(&mut self, duty: i16) {
        assert!((-DUTY_MAX..=DUTY_MAX).contains(&duty));
        self.off = false;
        self.duty = f64::from(duty) / f64::from(DUTY_MAX);
    }
    fn bridge_off(&mut self) {
        self.off = true;
        self.duty = 0.0;
    }
}

const SMALL: SweepConfig = SweepConfig {
    safe_torque_unm: 200_000,
    ramp_ticks: 5_000,
    pause_ticks: 200,
    max_dtheta_urad: 1_500_000,
    end_dtheta_urad: 20_000,
    timeout_ticks: 30_000,
    decimate: 10,
};

struct Run {
    phase: Phase,
    ticks: u32,
    records: Vec<grasp::LoopOutput>,
    inputs: Vec<Input>,
    max_ref: i32,
    min_ref: i32,
}

fn run(hw: &mut Spring, cfg: SweepConfig) -> (ControlLoop, Run) {
    let p = ControllerConfig::DEFAULT.params().unwrap();
    let mut lp = ControlLoop::for_sweep(&p, grasp::calibrate::Sweep::new(cfg).unwrap());
    let mut link = Link::new();
    let mut r = Run {
        phase: Phase::Idle,
        ticks: 0,
        records: vec![],
        inputs: vec![],
        max_ref: 0,
        min_ref: 0,
    };
    for _ in 0..200_000 {
        let out = grasp::loop_tick_dyn(&mut lp, &mut link, hw);
        r.ticks += 1;
        r.max_ref = r.max_ref.max(out.torque_ref_unm);
        r.min_ref = r.min_ref.min(out.torque_ref_unm);
        if lp.sweep_record() {
            r.records.push(out);
        }
        while let Some(i) = link.next_input() {
            r.inputs.push(i);
        }
        r.phase = lp.sweep_phase().unwrap();
        if matches!(r.phase, Phase::Done | Phase::Aborted(_)) {
            break;
        }
    }
    (lp, r)
}

#[test]
fn a_free_finger_is_swept_within_the_safe_torque_and_left_with_the_bridge_off() {
    let mut hw = Spring::new(0.5);
    let (lp, r) = run(&mut hw, SMALL);
    assert_eq!(
        r.phase,
        Phase::Done,
        "{:?} after {} ticks",
        r.inputs,
        r.ticks
    );
    // Closing reaches the safe torque (the finger's 0.4 rad there is inside the angle limit),
    // opening goes below zero only as far as it needs: a spring returns on its own.
    assert_eq!(r.max_ref, SMALL.safe_torque_unm);
    assert!(r.min_ref >= -SMALL.safe_torque_unm, "{}", r.min_ref);
    assert!(hw.off && !lp.driving(), "the bridge must end off");
    // The supervisor is told nothing: no start, no calibration to begin an approach on.
    assert!(r.inputs.is_empty(), "{:?}", r.inputs);
    // One row in `decimate` ticks, consecutive.
    assert!(r.records.len() > 500, "{}", r.records.len());
    for w in r.records.windows(2) {
        assert_eq!(w[1].tick - w[0].tick, u32::from(SMALL.decimate));
    }
    // The torque loop follows the reference on the rising ramp: measured T_a within 5 % of
    // the safe torque of the reference (the sweep is slow against the loop).
    let mid: Vec<_> = r
        .records
        .iter()
        .filter(|o| o.torque_ref_unm > SMALL.safe_torque_unm / 4)
        .collect();
    assert!(!mid.is_empty());
    for o in mid {
        let err = (o.torque_unm - o.torque_ref_unm).abs();
        assert!(err < SMALL.safe_torque_unm / 20, "{o:?}");
    }
    // After the end the loop keeps the bridge off.
    let mut link = Link::new();
    let mut lp = lp;
    for _ in 0..10 {
        let out = lp.tick(&mut hw, &mut link);
        assert_eq!((out.duty, lp.sweep_record()), (0, false));
    }
    assert!(hw.off);
}

#[test]
fn a_shorted_winding_trips_the_sweep_as_it_trips_a_grasp() {
    let mut hw = Spring::new(0.5);
    hw.leak_a = 0.6;
    let (lp, r) = run(&mut hw, SMALL);
    assert_eq!(r.phase, Phase::Aborted(AbortReason::Fault));
    assert!(
        matches!(
            r.inputs.as_slice(),
            [Input::LoopFault {
                reason: FaultReason::OverCurrent { .. } | FaultReason::AdcOffset { .. },
                ..
            }]
        ),
        "{:?}",
        r.inputs
    );
    assert!(hw.off && !lp.driving());
}

#[test]
fn a_finger_that_runs_away_is_stopped_at_the_angle_limit() {
    let mut hw = Spring::new(0.5);
    hw.runaway_after = Some(3_000);
    let (lp, r) = run(&mut hw, SMALL);
    assert_eq!(r.phase, Phase::Aborted(AbortReason::AngleLimit));
    assert!(hw.off && !lp.driving());
    assert!(r.ticks < SMALL.timeout_ticks);
}

#[test]
fn a_motor_that_does_not_turn_at_full_duty_is_a_stall() {
    let mut hw = Spring::new(0.5);
    hw.open_winding = true;
    let (lp, r) = run(&mut hw, SMALL);
    assert_eq!(r.phase, Phase::Aborted(AbortReason::Fault));
    assert!(
        matches!(
            r.inputs.as_slice(),
            [Input::LoopFault {
                reason: FaultReason::Stall,
                ..
            }]
        ),
        "{:?}",
        r.inputs
    );
    assert!(hw.off && !lp.driving());
}
