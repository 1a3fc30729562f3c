//! Instruction count of pts::pathfit::fit_path on thumbv7em (run under unicorn by count.py,
//! `count.sh`): `run` on Fx32, `run_f32` on the Cortex-M4F single-precision FPU, with
//! `PathFitConfig::DEFAULT` (the paper finger on the RE10 drive) and the case in INPUT.
#![no_std]
#![no_main]

use pts::fixed::Fx32;
use pts::pathfit::{fit_path, PathFitConfig, PathSample};
use pts::Model;

/// Filled by the harness: Fx32 bits of θa,c, T_a,c and N samples (θa, T_a).
#[no_mangle]
pub static mut INPUT: [i64; 2 + 3 * 256] = [0; 2 + 3 * 256];
#[no_mangle]
pub static mut N: u32 = 0;
/// The same input as f32 (filled by the harness).
#[no_mangle]
pub static mut INPUT_F32: [f32; 2 + 3 * 256] = [0.0; 2 + 3 * 256];
/// Outputs: k2 bits, σ bits, status (0 ok, 1 + error index otherwise).
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
    let r = fit_path(&model, &CFG, th_c, Some(ta_c), samples);
    let out = unsafe { &mut *core::ptr::addr_of_mut!(OUT) };
    match r {
        Ok(f) => {
            out[0] = f.k2_contact_m.to_bits();
            out[1] = f.sigma_k2_m.to_bits();
            out[2] = 0;
            out[3] = f.path_evals as i64;
            0
        }
        Err(_) => {
            out[2] = 1;
            1
        }
    }
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
        Err(_) => {
            out[2] = 1;
            1
        }
    }
}

const CFG: PathFitConfig = PathFitConfig::DEFAULT;

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}
