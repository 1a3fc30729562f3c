//! Instruction count of the path fit on thumbv7em (run under unicorn by emu.py, `count.sh`):
//! `run` = the generic `pathfit::fit_path` on Fx32, `run_f32` the same on the Cortex-M4F
//! single-precision FPU, `run_q` the firmware's integer fit `pathfit::q::fit_path_q` (its
//! table built by `init_q` beforehand, as the firmware does at init), with
//! `PathFitConfig::DEFAULT` (the paper finger on the RE10 drive) and the case in INPUT*.
#![no_std]
#![no_main]

use pts::fixed::Fx32;
use pathfit::q::{fit_path_q, PathTable, RawSample};
use pathfit::{fit_path, PathFit, PathFitConfig, PathFitError, PathSample};
use pts::{Finger, Model};

/// Filled by the harness: Fx32 bits of θa,c, T_a,c and N samples (θa, T_a).
#[no_mangle]
pub static mut INPUT: [i64; 2 + 3 * 256] = [0; 2 + 3 * 256];
#[no_mangle]
pub static mut N: u32 = 0;
/// The same input as f32 (filled by the harness).
#[no_mangle]
pub static mut INPUT_F32: [f32; 2 + 3 * 256] = [0.0; 2 + 3 * 256];
/// The same samples as the controller's integers: tick (100 µs), θa (µrad), T_a (µN·m),
/// in the firmware's buffer layout.
#[no_mangle]
pub static mut INPUT_RAW: [RawSample; 256] = [RawSample {
    tick: 0,
    theta_a_urad: 0,
    torque_unm: 0,
}; 256];
/// The integer fit's table, built by `init_q`.
static mut TABLE: Option<PathTable> = None;
/// Outputs: k2 bits, σ bits, status (0 ok, else [`status`] of the refusal), evaluations.
#[no_mangle]
pub static mut OUT: [i64; 4] = [0; 4];

#[no_mangle]
#[inline(never)]
pub extern "C" fn run() -> i32 {
    let input = unsafe { &*core::ptr::addr_of!(INPUT) };
    let n = unsafe { N } as usize;
    let model = match Model::<Fx32>::paper() {
        Ok(m) => m,
        Err(_) => return -1,
    };
    let th_c = Fx32::from_bits(input[0]);
    let ta_c = Fx32::from_bits(input[1]);
    let samples = input[2..2 + 3 * n.min(256)].chunks_exact(3).map(|c| PathSample {
        time_s: Fx32::from_bits(c[0]),
        theta_a_rad: Fx32::from_bits(c[1]),
        torque_nm: Fx32::from_bits(c[2]),
    });
    report(fit_path(&model, &CFG, th_c, Some(ta_c), samples))
}

/// Writes a fixed-point fit's k2, σ, status and evaluations to OUT; returns the status.
fn report(r: Result<PathFit<Fx32>, PathFitError>) -> i32 {
    let out = unsafe { &mut *core::ptr::addr_of_mut!(OUT) };
    match r {
        Ok(f) => {
            out[0] = f.k2_contact_m.to_bits();
            out[1] = f.sigma_k2_m.to_bits();
            out[2] = 0;
            out[3] = f.path_evals as i64;
            0
        }
        Err(e) => {
            out[2] = status(e);
            out[2] as i32
        }
    }
}

/// A refusal's status: 1 + its position in this list (checks compare the two back ends).
fn status(e: PathFitError) -> i64 {
    const KINDS: [&str; 8] = [
        "too_few_samples",
        "no_motion",
        "proximal_contact",
        "past_tip",
        "second_contact",
        "bad_fit",
        "not_determined",
        "no_convergence",
    ];
    let k = e.kind();
    KINDS
        .iter()
        .position(|x| *x == k)
        .map_or(KINDS.len() as i64 + 1, |i| i as i64 + 1)
}

/// The same fit on the Cortex-M4F single-precision FPU.
#[no_mangle]
#[inline(never)]
pub extern "C" fn run_f32() -> i32 {
    let input = unsafe { &*core::ptr::addr_of!(INPUT_F32) };
    let n = unsafe { N } as usize;
    let model = match Model::<f32>::paper() {
        Ok(m) => m,
        Err(_) => return -1,
    };
    let th_c = input[0];
    let ta_c = input[1];
    let samples = input[2..2 + 3 * n.min(256)].chunks_exact(3).map(|c| PathSample {
        time_s: c[0],
        theta_a_rad: c[1],
        torque_nm: c[2],
    });
    let r = fit_path(&model, &CFG, th_c, Some(ta_c), samples);
    let out = unsafe { &mut *core::ptr::addr_of_mut!(OUT) };
    match r {
        Ok(fit) => {
            out[0] = (fit.k2_contact_m as f64 * 4294967296.0) as i64;
            out[1] = (fit.sigma_k2_m as f64 * 4294967296.0) as i64;
            out[2] = 0;
            out[3] = fit.path_evals as i64;
            0
        }
        Err(e) => {
            out[2] = status(e);
            out[2] as i32
        }
    }
}

/// Builds the integer fit's table (the firmware does this once at init; not counted).
#[no_mangle]
#[inline(never)]
pub extern "C" fn init_q() -> i32 {
    let t = PathTable::new(&Finger::PAPER, &CFG, 1e-4).ok();
    let ok = t.is_some();
    unsafe { *core::ptr::addr_of_mut!(TABLE) = t };
    if ok {
        0
    } else {
        -1
    }
}

/// The firmware's integer fit (`pathfit::q`).
#[no_mangle]
#[inline(never)]
pub extern "C" fn run_q() -> i32 {
    let input = unsafe { &*core::ptr::addr_of!(INPUT) };
    let raw = unsafe { &*core::ptr::addr_of!(INPUT_RAW) };
    let n = unsafe { N } as usize;
    let Some(table) = (unsafe { &*core::ptr::addr_of!(TABLE) }) else {
        return -1;
    };
    let samples = raw[..n.min(256)].iter().copied();
    report(fit_path_q(
        table,
        Fx32::from_bits(input[0]),
        Some(Fx32::from_bits(input[1])),
        samples,
    ))
}

const CFG: PathFitConfig = PathFitConfig::DEFAULT;

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}
