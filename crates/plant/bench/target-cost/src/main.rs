//! Counts instructions of `Plant::step` on the firmware ISA (thumbv7em-none-eabihf, soft-float
//! f64), run under the unicorn emulator by `count.py`; see `run.sh`. Not a workspace member: a
//! bare-metal image with its own linker script and two MMIO writes (FPU enable, marker).
#![no_std]
#![no_main]
use core::panic::PanicInfo;

#[panic_handler]
fn panic(_: &PanicInfo) -> ! {
    mark(0xDEAD);
    loop {}
}

/// Marker word: the host hook records the instruction count at every write.
const MARK: *mut u32 = 0x2003_0000 as *mut u32;

#[inline(never)]
fn mark(v: u32) {
    unsafe { core::ptr::write_volatile(MARK, v) }
}

#[no_mangle]
pub extern "C" fn _start() -> ! {
    // FPU on (CPACR CP10/CP11 full access) — eabihf passes f64 in d-registers.
    unsafe { core::ptr::write_volatile(0xE000_ED88 as *mut u32, 0xF << 20) };
    mark(1);
    let scene = plant::Scene {
        start_theta_a_rad: Some(-0.2245),
        ..plant::scenes::table2()
    };
    let mut p = match plant::Plant::new(&scene) {
        Ok(p) => p,
        Err(_) => {
            mark(0xBAD);
            loop {}
        }
    };
    mark(2);
    let mut k: u32 = 0;
    while k < 400 {
        p.step(1.0);
        k += 1;
        mark(100 + (p.truth().contact as u32));
        while p.poll_event().is_some() {}
    }
    mark(3);
    // Micro: 100 linkage calls, 100 drive advances (8 substeps), 100 sensor samples.
    let f = plant::FingerGeom::PAPER;
    let mut acc = 0.0;
    mark(10);
    let mut i = 0;
    while i < 100 {
        acc += f
            .linkage(0.2 + i as f64 * 1e-4)
            .map(|l| l.x2)
            .unwrap_or(0.0);
        i += 1;
    }
    mark(11);
    let d = plant::drive::DriveParams::RE10_GP10A;
    let mut st = plant::drive::DriveState::default();
    let load = plant::drive::Load {
        theta_a_zero_rad: -0.85,
        theta_a0_rad: -0.2,
        t0_nm: 0.3,
        k_nm_per_rad: 6.0,
    };
    i = 0;
    while i < 100 {
        d.advance(
            &mut st,
            plant::drive::Input::Duty(0.5),
            &load,
            -0.85,
            20.0,
            1e-4,
        );
        i += 1;
    }
    mark(12);
    let sp = plant::sensors::SensorParams::DEFAULT;
    let mut rng = plant::sensors::Rng::new(1);
    let mut c: u32 = 0;
    i = 0;
    while i < 100 {
        c = c.wrapping_add(sp.adc_code(0.1, rng.normal()) as u32);
        i += 1;
    }
    mark(13);
    if acc == 1.2345 || st.angle_rad == 1.0 || c == 7 {
        mark(99);
    }
    mark(4);
    loop {}
}
