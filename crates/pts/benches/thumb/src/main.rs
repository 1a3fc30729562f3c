//! Instruction-count harness (see `../count.py`). Two entry points with C ABI:
//! `bench_init()` builds every model and table once; `bench_run(id, inp, out)` runs one
//! operation on inputs read from `inp` (8-byte slots, each value in its back end's native
//! bits) and writes results to `out`. The emulator counts the instructions of one
//! `bench_run` call; `id = 0` does nothing and gives the dispatch overhead.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::{addr_of_mut, read_volatile, write_volatile};

use grasp::{
    ControlLoop, Controller, ControllerConfig, EstimateRequest, EstimateResult, Estimator,
    Hardware, Link, Located, Sample, Supervisor, TwoPointTable,
};
use pathfit::q::PathTable;
use pts::fixed::{Fx16, Fx24, Fx32};
use pts::table::FreeTable;
use pts::{Estimate, Finger, Model, Phalanx, PtsError, Real};

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}

/// A value with a native 8-byte slot encoding.
trait Slot: Real {
    fn get(p: *const u64) -> Self;
    fn put(self, p: *mut u64);
}
impl Slot for f64 {
    fn get(p: *const u64) -> Self {
        f64::from_bits(unsafe { read_volatile(p) })
    }
    fn put(self, p: *mut u64) {
        unsafe { write_volatile(p, self.to_bits()) }
    }
}
impl Slot for f32 {
    fn get(p: *const u64) -> Self {
        f32::from_bits(unsafe { read_volatile(p) } as u32)
    }
    fn put(self, p: *mut u64) {
        unsafe { write_volatile(p, self.to_bits() as u64) }
    }
}
impl Slot for Fx32 {
    fn get(p: *const u64) -> Self {
        Fx32::from_bits(unsafe { read_volatile(p) } as i64)
    }
    fn put(self, p: *mut u64) {
        unsafe { write_volatile(p, self.to_bits() as u64) }
    }
}
impl Slot for Fx24 {
    fn get(p: *const u64) -> Self {
        Fx24::from_bits(unsafe { read_volatile(p) } as u32 as i32)
    }
    fn put(self, p: *mut u64) {
        unsafe { write_volatile(p, self.to_bits() as u32 as u64) }
    }
}
impl Slot for Fx16 {
    fn get(p: *const u64) -> Self {
        Fx16::from_bits(unsafe { read_volatile(p) } as u32 as i32)
    }
    fn put(self, p: *mut u64) {
        unsafe { write_volatile(p, self.to_bits() as u32 as u64) }
    }
}

/// Integer-only stand-in for the board, driven like grasp's quasi-static mock
/// (MODEL.md Table 2 contact: free stiffness to θa,c, then K_c = 6.7249 N·m/rad).
/// count.py excludes the instructions spent inside these methods from the tick count.
struct Mock {
    duty: i32,
    off: bool,
    /// θa − θa,rest in encoder counts, Q16.
    pos_q16: i64,
    /// Motor torque at full duty (µN·m).
    t_full_unm: i64,
    /// ADC codes at full duty.
    codes_full: i64,
    /// Contact torque (µN·m) and contact position (counts, Q16).
    tc_unm: i64,
    posc_q16: i64,
    /// Counts (Q16) per µN·m, free and in contact.
    free_q16: i64,
    contact_q16: i64,
    /// Largest move per update (counts, Q16).
    speed_q16: i64,
}

impl Mock {
    fn new(d: &grasp::DriveConfig) -> Self {
        let cpr = 1.0 / d.rad_per_count();
        let i_full = d.bus_v / d.resistance_ohm;
        let (theta_rest, theta_c, ta_c, kc) = (-0.850_360_8, -0.223_771, 0.340_821, 6.7249);
        let k_free = ta_c / (theta_c - theta_rest);
        let q = 65536.0;
        Mock {
            duty: 0,
            off: true,
            pos_q16: 0,
            t_full_unm: (i_full * d.torque_per_amp() * 1e6) as i64,
            codes_full: (i_full / d.amps_per_code) as i64,
            tc_unm: (ta_c * 1e6) as i64,
            posc_q16: ((theta_c - theta_rest) * cpr * q) as i64,
            free_q16: (cpr * q / (k_free * 1e6)) as i64,
            contact_q16: (cpr * q / (kc * 1e6)) as i64,
            speed_q16: (1e-3 * cpr * q) as i64,
        }
    }
    fn torque_unm(&self) -> i64 {
        if self.off {
            0
        } else {
            self.t_full_unm * self.duty as i64 / grasp::DUTY_MAX as i64
        }
    }
    fn settle(&mut self) {
        let t = self.torque_unm();
        let target = if t <= self.tc_unm {
            t * self.free_q16
        } else {
            self.posc_q16 + (t - self.tc_unm) * self.contact_q16
        };
        self.pos_q16 += (target - self.pos_q16).clamp(-self.speed_q16, self.speed_q16);
    }
}

impl Hardware for Mock {
    #[inline(never)]
    fn encoder_count(&mut self) -> u16 {
        ((self.pos_q16 >> 16) + 1000) as u16
    }
    #[inline(never)]
    fn current_raw(&mut self) -> u16 {
        let c = if self.off {
            0
        } else {
            self.codes_full * self.duty as i64 / grasp::DUTY_MAX as i64
        };
        (2048 + c).clamp(0, 4095) as u16
    }
    #[inline(never)]
    fn set_duty(&mut self, duty: i16) {
        self.off = false;
        self.duty = duty as i32;
        self.settle();
    }
    #[inline(never)]
    fn bridge_off(&mut self) {
        self.off = true;
        self.settle();
    }
}

struct State {
    m64: Model<f64>,
    m32: Model<f32>,
    mx32: Model<Fx32>,
    mx16: Model<Fx16>,
    mx24: Model<Fx24>,
    tx24: FreeTable<Fx24>,
    t64: FreeTable<f64>,
    t32: FreeTable<f32>,
    tx32: FreeTable<Fx32>,
    tx16: FreeTable<Fx16>,
    ctl: Parts,
    mock: Mock,
    /// The firmware's estimate tables for the paper's finger (grasp's constructors, as the
    /// firmware's init calls them) and the request the estimate ops run on.
    fw_tp: TwoPointTable,
    fw_pt: PathTable,
    req: EstimateRequest,
}

/// The controller split as the firmware runs it: the loop (sampling task) and the
/// supervisor (state machine, lower priority), joined by their link.
struct Parts {
    lp: ControlLoop,
    link: Link,
    sup: Supervisor,
}

static mut STATE: MaybeUninit<State> = MaybeUninit::uninit();

fn controller() -> Result<(Parts, Mock), ()> {
    // As grasp's quasi-static mock test (crates/grasp/tests/mock.rs).
    let cfg = ControllerConfig {
        damping_nm_s_per_rad: 0.0,
        approach_speed_max_rad_s: 100.0,
        detect_min_rise_nm: 0.002,
        // The mock has no back-EMF (as grasp's mock test); the check still runs every tick.
        emf_mismatch_v: 1000.0,
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(0.5);
    let mock = Mock::new(&cfg.drive);
    let (lp, link, sup) = Controller::new(cfg).map_err(|_| ())?.into_parts();
    Ok((Parts { lp, link, sup }, mock))
}

fn build() -> Result<State, PtsError> {
    let f = Finger::PAPER;
    let (ctl, mock) = controller().map_err(|_| PtsError::InvalidFinger)?;
    Ok(State {
        m64: Model::new(&f)?,
        m32: Model::new(&f)?,
        mx32: Model::new(&f)?,
        mx16: Model::new(&f)?,
        mx24: Model::new(&f)?,
        tx24: FreeTable::new(&f)?,
        t64: FreeTable::new(&f)?,
        t32: FreeTable::new(&f)?,
        tx32: FreeTable::new(&f)?,
        tx16: FreeTable::new(&f)?,
        ctl,
        mock,
        fw_tp: grasp::two_point_table(&f)?,
        fw_pt: grasp::path_table(&f, &grasp::DriveConfig::DEFAULT, 100_000)?,
        req: EstimateRequest::EMPTY,
    })
}

/// Word `i` of the input area (i32).
#[inline(always)]
fn word(inp: *const u64, i: usize) -> i32 {
    unsafe { read_volatile((inp as *const i32).wrapping_add(i)) }
}

/// Loads a request from the input area (count.py's layout): sample_ticks, path_stride,
/// ΔT_a cmd, detection K, dt_ns, #pre, #path, then contact, seat, seat2, end and the pre and
/// path samples, four words each (tick, θa µrad, T_a µN·m, T_ref µN·m). 0 on success.
fn load_request(s: &mut State, inp: *const u64) -> i32 {
    let sample = |i: usize| Sample {
        tick: word(inp, i) as u32,
        theta_a_urad: word(inp, i + 1),
        torque_unm: word(inp, i + 2),
        torque_ref_unm: word(inp, i + 3),
    };
    let r = &mut s.req;
    r.sample_ticks = word(inp, 0) as u32;
    r.path_stride = word(inp, 1) as u32;
    r.delta_ta_cmd_unm = word(inp, 2);
    r.detect_k_unm_per_rad = word(inp, 3);
    r.dt_ns = word(inp, 4) as u32;
    let (n_pre, n_path) = (word(inp, 5) as usize, word(inp, 6) as usize);
    r.contact = sample(7);
    r.seat = sample(11);
    r.seat2 = sample(15);
    r.end = sample(19);
    r.pre.clear();
    r.path.clear();
    for k in 0..n_pre {
        if r.pre.push(sample(23 + 4 * k)).is_err() {
            return 1;
        }
    }
    for k in 0..n_path {
        if r.path.push(sample(23 + 4 * (n_pre + k))).is_err() {
            return 2;
        }
    }
    if s.fw_pt.tick_ns() != r.dt_ns {
        match grasp::path_table(&Finger::PAPER, &grasp::DriveConfig::DEFAULT, r.dt_ns) {
            Ok(t) => s.fw_pt = t,
            Err(_) => return 3,
        }
    }
    0
}

/// Writes an estimate's figures to `out` (i32 words: located, k2 µm or i32::MIN, K̂c,
/// θa,c, T_a,c; on error the kind's name as bytes); 0 for a result, 1 for an error.
#[inline(never)]
fn put_result(r: &Result<EstimateResult, grasp::EstimateError>, out: *mut u64) -> i32 {
    let o = out as *mut i32;
    match r {
        Ok(r) => {
            let located = match r.located {
                Located::Proximal => 0,
                Located::Distal => 1,
                Located::ProximalOrNearO2 => 2,
            };
            let v = [
                located,
                r.k2_um.unwrap_or(i32::MIN),
                r.kc_hat_unm_per_rad,
                r.theta_a_c_urad,
                r.ta_c_unm,
            ];
            for (i, x) in v.into_iter().enumerate() {
                unsafe { write_volatile(o.wrapping_add(i), x) };
            }
            0
        }
        Err(e) => {
            for (i, b) in e.kind().bytes().take(31).chain([0]).enumerate() {
                unsafe { write_volatile((out as *mut u8).wrapping_add(i), b) };
            }
            1
        }
    }
}

/// Controller state as a small integer for count.py.
fn state_code(st: grasp::State) -> i32 {
    use grasp::State as S;
    match st {
        S::Init => 0,
        S::Calibrating => 1,
        S::Approach => 2,
        S::Seating => 3,
        S::Step => 4,
        S::Settling => 5,
        S::Estimating => 6,
        S::Holding => 7,
        S::Releasing => 8,
        S::Done => 9,
        S::Opening => 18,
        S::Fault(r) => {
            use grasp::FaultReason as F;
            10 + match r {
                F::EncoderJump { .. } => 1,
                F::EncoderMismatch { .. } => 2,
                F::AdcCode { .. } => 3,
                F::AdcOffset { .. } => 4,
                F::OverCurrent { .. } => 5,
                F::Stall => 6,
                _ => 7,
            }
        }
    }
}

/// Builds everything; 0 on success. Not counted.
#[no_mangle]
pub extern "C" fn bench_init() -> i32 {
    match build() {
        Ok(s) => {
            unsafe { (*addr_of_mut!(STATE)).write(s) };
            0
        }
        Err(e) => 100 + e as i32,
    }
}

fn code<R: Real>(r: &Result<Estimate<R>, PtsError>) -> i32 {
    match r {
        Ok(e) => match e.contact.phalanx {
            Phalanx::Distal => 0,
            Phalanx::Proximal => 1,
            Phalanx::None => 2,
        },
        Err(e) => 100 + *e as i32,
    }
}

#[inline(always)]
fn args<R: Slot>(inp: *const u64) -> [R; 4] {
    [0, 1, 2, 3].map(|i| R::get(inp.wrapping_add(i)))
}

/// Writes k2 (0 when none) and K̂c, returns the outcome code.
#[inline(always)]
fn report<R: Slot>(r: Result<Estimate<R>, PtsError>, out: *mut u64) -> i32 {
    if let Ok(e) = &r {
        e.contact.k2.unwrap_or(R::zero()).put(out);
        e.kc_hat.put(out.wrapping_add(1));
    }
    code(&r)
}

#[inline(always)]
fn free<R: Slot>(r: Result<pts::Config<R>, PtsError>, out: *mut u64) -> i32 {
    match r {
        Ok(c) => {
            c.theta2.put(out);
            0
        }
        Err(e) => 100 + e as i32,
    }
}

/// One operation: 50 loads an estimate request, 51/52 run the firmware's two-point /
/// path-fit estimate entry on it; ids 1‥8 full estimate, 11‥18 free-motion configuration from θa
/// (f64, f32, Fx32, Fx16, then the table variants in the same order), 9/10 and 19/20
/// the same for Fx24 and table+Fx24, 30 the f64
/// measurement generator, 40 one control-loop tick, 44 the supervisor on what it handed
/// over, 41 serve a pending estimate request, 42 reset the controller, 43 the fault's name.
#[no_mangle]
pub extern "C" fn bench_run(id: u32, inp: *const u64, out: *mut u64) -> i32 {
    let s = unsafe { (*addr_of_mut!(STATE)).assume_init_mut() };
    match id {
        1 => {
            let a = args::<f64>(inp);
            report(s.m64.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        2 => {
            let a = args::<f32>(inp);
            report(s.m32.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        3 => {
            let a = args::<Fx32>(inp);
            report(s.mx32.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        4 => {
            let a = args::<Fx16>(inp);
            report(s.mx16.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        5 => {
            let a = args::<f64>(inp);
            report(s.t64.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        6 => {
            let a = args::<f32>(inp);
            report(s.t32.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        7 => {
            let a = args::<Fx32>(inp);
            report(s.tx32.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        8 => {
            let a = args::<Fx16>(inp);
            report(s.tx16.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        9 => {
            let a = args::<Fx24>(inp);
            report(s.mx24.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        10 => {
            let a = args::<Fx24>(inp);
            report(s.tx24.estimate_two_point(a[0], a[1], a[2], a[3]), out)
        }
        19 => free(s.mx24.free_from_theta_a(Fx24::get(inp)), out),
        20 => free(s.tx24.free_from_theta_a(Fx24::get(inp)).map(|c| c.0), out),
        11 => free(s.m64.free_from_theta_a(f64::get(inp)), out),
        12 => free(s.m32.free_from_theta_a(f32::get(inp)), out),
        13 => free(s.mx32.free_from_theta_a(Fx32::get(inp)), out),
        14 => free(s.mx16.free_from_theta_a(Fx16::get(inp)), out),
        15 => free(s.t64.free_from_theta_a(f64::get(inp)).map(|c| c.0), out),
        16 => free(s.t32.free_from_theta_a(f32::get(inp)).map(|c| c.0), out),
        17 => free(s.tx32.free_from_theta_a(Fx32::get(inp)).map(|c| c.0), out),
        18 => free(s.tx16.free_from_theta_a(Fx16::get(inp)).map(|c| c.0), out),
        30 => {
            // (T_a,c, k2, ΔT_a) → (θa,c, θa) of a quasi-static contact (f64 model).
            let [ta_c, k2, dta, _] = args::<f64>(inp);
            let Ok(cfg) = s.m64.free_from_torque(ta_c) else {
                return 1;
            };
            let Ok(kc) = s.m64.kc_distal(cfg.theta2, ta_c, k2) else {
                return 2;
            };
            cfg.theta_a.put(out);
            (cfg.theta_a + dta / kc).put(out.wrapping_add(1));
            0
        }
        40 => {
            // The sampling task's work: one loop tick.
            let o = grasp::loop_tick_dyn(&mut s.ctl.lp, &mut s.ctl.link, &mut s.mock);
            o.sample_ready as i32
        }
        44 => {
            // The supervisor on what the tick handed over (the firmware's next task).
            let ready = grasp::supervise_dyn(&mut s.ctl.sup, &mut s.ctl.link);
            ready as i32 + 2 * state_code(s.ctl.sup.state())
        }
        43 => {
            // The fault's name into `out` (diagnostics for count.py).
            if let grasp::State::Fault(r) = s.ctl.sup.state() {
                for (i, b) in r.kind().bytes().take(16).enumerate() {
                    unsafe { write_volatile((out as *mut u8).wrapping_add(i), b) };
                }
            }
            0
        }
        50 => load_request(s, inp),
        51 => {
            // The firmware's two-point estimate task: request → result (src/ctl.rs calls
            // this very function). count.py counts only the instructions inside it.
            s.req.estimator = Estimator::TwoPoint;
            let r = grasp::two_point_fw(&s.fw_tp, &s.req);
            put_result(&r, out)
        }
        52 => {
            // The firmware's path-fit estimate task, likewise.
            s.req.estimator = Estimator::PathFit;
            let r = grasp::path_fit_fw(&s.fw_pt, &s.req);
            put_result(&r, out)
        }
        41 => match s.ctl.sup.take_request() {
            Some(req) => {
                let r = grasp::two_point_fw(&s.fw_tp, &req);
                s.ctl.sup.deliver(r);
                s.ctl.sup.publish(&mut s.ctl.link);
                1
            }
            None => 0,
        },
        42 => match controller() {
            Ok((c, m)) => {
                s.ctl = c;
                s.mock = m;
                0
            }
            Err(()) => 1,
        },
        _ => 0,
    }
}
