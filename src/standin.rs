//! Stand-in for crates/grasp and crates/plant while they are being written: a toy first-order
//! finger and a minimal grasp sequence with the same shape as the grasp interface
//! (`tick` → `EstimateRequest` → `run_estimate` → `deliver`, `poll_event`), so the QEMU
//! pipeline (RTIC tasks, defmt over semihosting, host decoding, exit status) works end to end.
//! Replaced by the real crates as they land.

/// Full-scale duty (same convention as `grasp::DUTY_MAX`).
pub const DUTY_MAX: i16 = 10_000;

/// What a board provides (same shape as `grasp::Hardware`).
pub trait Hardware {
    /// Quadrature ×4 encoder count, wrapping.
    fn encoder_count(&mut self) -> u16;
    /// 12-bit ADC code of the shunt amplifier.
    fn current_raw(&mut self) -> u16;
    /// Signed duty, ±DUTY_MAX.
    fn set_duty(&mut self, duty: i16);
    /// Safe state.
    fn bridge_off(&mut self);
}

const RAD_PER_COUNT: f64 = 2.0 * core::f64::consts::PI / (64.0 * 256.0);
const NM_PER_CODE: f64 = 2.5e-4 * 3.95e-3 * 256.0 * 0.7;
const THETA_REST: f64 = -0.850_360_8;

/// Grasp state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum State {
    /// Current offset calibration, bridge off.
    Calibrate,
    /// Torque ramp until contact.
    Approach,
    /// Torque step after contact.
    Step,
    /// Waiting for the estimate.
    Estimate,
    /// Holding.
    Hold,
    /// Bridge off after a fault.
    Fault,
}

/// Transitions with their data (µrad, µN·m).
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum Event {
    /// Calibration done.
    Calibrated { offset_code: u16 },
    /// First contact.
    Contact { theta_a_urad: i32, ta_unm: i32 },
    /// Step settled, estimate requested.
    Settled { theta_a_urad: i32, ta_unm: i32 },
    /// Estimate delivered.
    Estimated { k2_um: i32, kc_unm_per_rad: i32 },
    /// Fault.
    Fault,
}

/// What tick() reports.
#[derive(Clone, Copy, Debug)]
pub struct TickOutput {
    /// θa (µrad).
    pub theta_a_urad: i32,
    /// T_a (µN·m).
    pub ta_unm: i32,
    /// State after the tick.
    pub state: State,
    /// Set once when the estimate is due.
    pub estimate_request: Option<EstimateRequest>,
}

/// Two-point data for the estimator.
#[derive(Clone, Copy, Debug)]
pub struct EstimateRequest {
    theta_a_c: f64,
    ta_c: f64,
    theta_a: f64,
    ta: f64,
}

/// Estimate (k2 in µm, or the error).
pub type EstimateResult = Result<(i32, i32), pts::PtsError>;

/// Runs the paper's estimator (f64 reference back end).
pub fn run_estimate(req: &EstimateRequest) -> EstimateResult {
    let m = pts::Model::<f64>::new(&crate::config::FINGER)?;
    let e = m.estimate_two_point(req.theta_a_c, req.ta_c, req.theta_a, req.ta)?;
    let k2 = e.contact.k2.unwrap_or(0.0);
    Ok(((k2 * 1e6) as i32, (e.kc_hat * 1e6) as i32))
}

/// Minimal grasp sequence.
pub struct Controller {
    state: State,
    ticks: u32,
    offset: i32,
    duty: i32,
    contact: (f64, f64),
    event: Option<Event>,
}

impl Controller {
    /// New controller in Calibrate.
    pub const fn new() -> Self {
        Self {
            state: State::Calibrate,
            ticks: 0,
            offset: 0,
            duty: 0,
            contact: (0.0, 0.0),
            event: None,
        }
    }
    /// One control period.
    pub fn tick(&mut self, hw: &mut impl Hardware) -> TickOutput {
        self.ticks += 1;
        let theta = THETA_REST + (hw.encoder_count() as i16) as f64 * RAD_PER_COUNT;
        let code = hw.current_raw() as i32;
        let ta = (code - self.offset) as f64 * NM_PER_CODE;
        let mut req = None;
        match self.state {
            State::Calibrate => {
                self.offset += code;
                if self.ticks == 64 {
                    self.offset /= 64;
                    self.event = Some(Event::Calibrated {
                        offset_code: self.offset as u16,
                    });
                    self.state = State::Approach;
                    self.ticks = 0;
                    self.offset = self.offset.max(0);
                } else if self.ticks < 64 {
                    // keep summing
                }
            }
            State::Approach => {
                self.duty += 4;
                if theta > -0.6 {
                    self.contact = (theta, ta);
                    self.event = Some(Event::Contact {
                        theta_a_urad: (theta * 1e6) as i32,
                        ta_unm: (ta * 1e6) as i32,
                    });
                    self.state = State::Step;
                    self.ticks = 0;
                    self.duty += 1500;
                }
                if self.duty > DUTY_MAX as i32 {
                    self.state = State::Fault;
                    self.event = Some(Event::Fault);
                }
            }
            State::Step => {
                if self.ticks == 300 {
                    req = Some(EstimateRequest {
                        theta_a_c: self.contact.0,
                        ta_c: self.contact.1,
                        theta_a: theta,
                        ta,
                    });
                    self.event = Some(Event::Settled {
                        theta_a_urad: (theta * 1e6) as i32,
                        ta_unm: (ta * 1e6) as i32,
                    });
                    self.state = State::Estimate;
                }
            }
            State::Estimate | State::Hold => {}
            State::Fault => self.duty = 0,
        }
        if self.state == State::Fault {
            hw.bridge_off();
        } else {
            hw.set_duty(self.duty.clamp(-(DUTY_MAX as i32), DUTY_MAX as i32) as i16);
        }
        TickOutput {
            theta_a_urad: (theta * 1e6) as i32,
            ta_unm: (ta * 1e6) as i32,
            state: self.state,
            estimate_request: req,
        }
    }
    /// Gives the estimate back.
    pub fn deliver(&mut self, res: EstimateResult) {
        self.event = Some(match res {
            Ok((k2_um, kc)) => Event::Estimated {
                k2_um,
                kc_unm_per_rad: kc,
            },
            Err(_) => Event::Fault,
        });
        self.state = if res.is_ok() { State::Hold } else { State::Fault };
    }
    /// Next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.event.take()
    }
    /// Current state.
    pub fn state(&self) -> State {
        self.state
    }
}

/// Toy plant: first-order actuator angle against a spring, stiffer after contact at −0.6 rad.
pub struct ToyPlant {
    theta: f64,
    ta: f64,
    /// Simulated time (s).
    pub t_s: f64,
}

impl ToyPlant {
    /// At rest.
    pub const fn new() -> Self {
        Self {
            theta: THETA_REST,
            ta: 0.0,
            t_s: 0.0,
        }
    }
    /// One 1 ms step with this duty (±1).
    pub fn step(&mut self, duty: f64) {
        self.ta = duty * 0.3;
        let k = if self.theta > -0.6 { 8.0 } else { 0.6 };
        let rest = if self.theta > -0.6 {
            -0.6 - 0.6 * 0.6 / 8.0 + (THETA_REST + 0.6)
        } else {
            THETA_REST
        };
        let _ = rest;
        let torque_spring = if self.theta > -0.6 {
            0.6 * (-0.6 - THETA_REST) + 8.0 * (self.theta + 0.6)
        } else {
            0.6 * (self.theta - THETA_REST)
        };
        let _ = k;
        self.theta += (self.ta - torque_spring) * 0.02;
        self.t_s += 1e-3;
    }
    /// Encoder count.
    pub fn encoder_count(&self) -> u16 {
        (((self.theta - THETA_REST) / RAD_PER_COUNT) as i32) as u16
    }
    /// ADC code.
    pub fn current_adc(&self) -> u16 {
        (2048.0 + self.ta / NM_PER_CODE).clamp(0.0, 4095.0) as u16
    }
    /// θa (rad).
    pub fn theta_a(&self) -> f64 {
        self.theta
    }
}
