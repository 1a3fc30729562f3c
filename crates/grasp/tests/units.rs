//! Sensor conditioning and the torque loop against independent f64 arithmetic from the
//! drive constants (not the code's own integer formulas).
use grasp::config::HISTORY;
use grasp::sensors::{counts_to_urad, CurrentSense, Encoder};
use grasp::torque_loop::TorqueLoop;
use grasp::{ControllerConfig, DriveConfig, DUTY_MAX};

fn params() -> grasp::config::Params {
    ControllerConfig::DEFAULT
        .params()
        .expect("default config is valid")
}

#[test]
fn encoder_unwraps_across_the_16_bit_boundary() {
    let p = params();
    let mut e = Encoder::new(65_500);
    let mut raw: u16 = 65_500;
    let mut total = 0i32;
    for _ in 0..100 {
        raw = raw.wrapping_add(13);
        total += 13;
        assert_eq!(e.update(raw, p.encoder_max_step), Ok(total));
    }
    for _ in 0..300 {
        raw = raw.wrapping_sub(7);
        total -= 7;
        assert_eq!(e.update(raw, p.encoder_max_step), Ok(total));
    }
    // θa: rest + counts · 2π/(counts/rev · ratio), against f64.
    let d = DriveConfig::DEFAULT;
    let want = d.theta_a_rest_rad
        + f64::from(total) * 2.0 * std::f64::consts::PI / (d.encoder_counts_per_rev * d.gear_ratio);
    let got = f64::from(e.theta_a_urad(&p)) * 1e-6;
    assert!((got - want).abs() < 2e-6, "{got} vs {want}");
    // Across the working range (θa − θa,rest < 2.5 rad ≈ 78 000 counts) within 2 µrad;
    // far outside it (1e6 counts, 31 rad) the Q16 gain rounding grows to < 8 µrad.
    for (counts, tol) in [(78_000, 2e-6), (-78_000, 2e-6), (1_000_000, 8e-6)] {
        let want = d.theta_a_rest_rad + f64::from(counts) * d.rad_per_count();
        let got = f64::from(counts_to_urad(counts, &p)) * 1e-6;
        assert!((got - want).abs() < tol, "{counts}: {got} vs {want}");
    }
}

#[test]
fn impossible_encoder_jump_is_refused() {
    let p = params();
    let mut e = Encoder::new(0);
    assert!(e.update(10, p.encoder_max_step).is_ok());
    let j = e.update(10 + 1000, p.encoder_max_step).unwrap_err();
    assert_eq!(j.step_counts, 1000);
    // State unchanged by the refused reading.
    assert_eq!(e.counts(), 10);
    // A jump of more than 2^15 wraps to the other sign and is refused too.
    assert!(e
        .update(10u16.wrapping_add(40_000), p.encoder_max_step)
        .is_err());
}

#[test]
fn current_and_torque_from_adc_codes() {
    let p = params();
    let d = DriveConfig::DEFAULT;
    let mut c = CurrentSense::new(&p);
    // Offset calibration: codes alternating 2051/2052 → mean 2051.5.
    for i in 0..256 {
        c.calib_add(if i % 2 == 0 { 2051 } else { 2052 });
    }
    assert_eq!(c.calib_finish(&p), Ok(2051 * 256 + 128));
    for code in [0u16, 1000, 2051, 2052, 3000, 4095] {
        let amps = (f64::from(code) - 2051.5) * d.amps_per_code;
        let nm = amps * d.kt_nm_per_a * d.gear_ratio * d.efficiency;
        let got_a = c.current_ua(code, &p) as f64 * 1e-6;
        let got_nm = f64::from(c.torque_unm(code, &p)) * 1e-6;
        assert!(
            (got_a - amps).abs() < 2e-6,
            "code {code}: {got_a} A vs {amps}"
        );
        assert!(
            (got_nm - nm).abs() < 5e-6,
            "code {code}: {got_nm} N·m vs {nm}"
        );
    }
    // An offset far from mid-scale is refused (sensor fault).
    let mut c = CurrentSense::new(&p);
    for _ in 0..256 {
        c.calib_add(3000);
    }
    assert!(c.calib_finish(&p).is_err());
}

#[test]
fn torque_loop_limits_and_recovers_without_windup() {
    let p = params();
    let d = DriveConfig::DEFAULT;
    let mut tl = TorqueLoop::new();
    // A static drive: torque = duty · V/R · kt·N·η. Ask for more than the drive can give.
    let stall = d.bus_v / d.resistance_ohm * d.torque_per_amp();
    let mut meas = 0.0f64;
    let ask = (stall * 2.0 * 1e6) as i32;
    for _ in 0..2000 {
        let duty = tl.update(ask, (meas * 1e6) as i32, &p);
        assert!(duty.abs() <= DUTY_MAX);
        meas = f64::from(duty) / f64::from(DUTY_MAX) * stall;
    }
    assert!(tl.saturated());
    // Now ask for 0.3 N·m: without windup it gets there within a few dozen ticks.
    let mut n = 0;
    for i in 0..200 {
        let duty = tl.update(300_000, (meas * 1e6) as i32, &p);
        meas = f64::from(duty) / f64::from(DUTY_MAX) * stall;
        if (meas - 0.3).abs() < 0.003 {
            n = i;
            break;
        }
    }
    assert!(n > 0 && n < 50, "recovered after {n} ticks, at {meas}");
    assert!(!tl.saturated());
}

#[test]
fn config_refuses_nonsense_and_history_is_sane() {
    const { assert!(HISTORY >= 32) };
    let mut c = ControllerConfig::DEFAULT;
    c.drive.gear_ratio = f64::NAN;
    assert!(c.params().is_err());
    let mut c = ControllerConfig::DEFAULT;
    c.delta_ta_nm = 0.01; // below 2 × seat_above
    assert!(c.params().is_err());
    let mut c = ControllerConfig::DEFAULT;
    c.sample_s = 1.0; // 10 000 ticks per sample
    assert!(c.params().is_err());
}

#[test]
fn memory_footprint_is_bounded() {
    use core::mem::size_of;
    let c = size_of::<grasp::Controller>();
    let r = size_of::<grasp::EstimateRequest>();
    let e = size_of::<grasp::Event>();
    println!("Controller {c} B, EstimateRequest {r} B, Event {e} B (host layout)");
    // Fits a small Cortex-M RAM with room to spare (target layout is no larger: i64 fields
    // align to 8 on both).
    assert!(c < 8 * 1024, "Controller {c} B");
    assert!(r < 4 * 1024, "EstimateRequest {r} B");
}
