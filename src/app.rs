//! The RTIC application: three priorities, one job each.
//!
//! | prio | task        | kind                    | work                                                  |
//! |------|-------------|-------------------------|-------------------------------------------------------|
//! | 3    | `sample`    | hardware, `ADC` line, 10 kHz | read encoder + current, `Controller::tick`, set the duty, forward events |
//! | 2    | `estimate`  | software (async)        | `take_request`, `run_estimate`, `deliver`             |
//! | 1    | `telemetry` | software (async)        | defmt: every event, θa/T_a/state decimated to 50 Hz   |
//!
//! The control task never waits: it hands data on with `try_send` and counts what a full
//! queue drops. Controller and board are shared with the estimate task only, which locks them
//! for `take_request` and `deliver` (a copy of the request, a few hundred cycles).

#[cfg_attr(
    feature = "qemu",
    rtic::app(device = crate::sim::pac, dispatchers = [UART0RX, UART0TX], peripherals = false)
)]
#[cfg_attr(
    not(feature = "qemu"),
    rtic::app(device = stm32f4xx_hal::pac, dispatchers = [SPI2, SPI3], peripherals = true)
)]
mod app {
    use core::sync::atomic::Ordering;

    use grasp::Controller;
    use rtic_sync::channel::{Receiver, Sender};
    use rtic_sync::make_channel;

    use crate::ctl;
    use crate::platform::{self, Board};
    use crate::telemetry::{self as tm, Done, Msg, QUEUE};

    #[shared]
    struct Shared {
        ctrl: Controller,
        board: Board,
    }

    #[local]
    struct Local {
        tel_tx: Sender<'static, Msg, QUEUE>,
        decimation: u32,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let (tel_tx, tel_rx) = make_channel!(Msg, QUEUE);
        #[cfg(feature = "qemu")]
        let (board, cfg) = platform::init(cx.core);
        #[cfg(not(feature = "qemu"))]
        let (board, cfg) = platform::init(cx.core, cx.device);
        defmt::info!(
            "BOOT finger={=str} l2_um={=u32} scene={=str} board={=str} dt_us={=u32}",
            crate::config::FINGER_NAME,
            (crate::config::FINGER.l2 * 1e6) as u32,
            crate::config::SCENE,
            platform::NAME,
            (cfg.drive.dt_s * 1e6) as u32
        );
        let decimation = ctl::decimation(&cfg.drive);
        // Calibration of the work counter: `delay(n)` is n + 1 passes of `subs; bne`, i.e.
        // 200 002 instructions (QEMU icount: stamps × 40; board: CPU cycles of that loop).
        let c0 = platform::stamp();
        cortex_m::asm::delay(100_000);
        defmt::info!(
            "CAL instructions=200002 stamps={=u32}",
            platform::stamp().wrapping_sub(c0)
        );
        let ctrl = match Controller::new(cfg) {
            Ok(c) => c,
            Err(_) => {
                defmt::error!("CONFIG rejected by grasp: bridge stays off");
                platform::safe_state();
                platform::halt(4)
            }
        };
        telemetry::spawn(tel_rx).ok();
        (Shared { ctrl, board }, Local { tel_tx, decimation })
    }

    /// Sleep between interrupts (on QEMU with `-icount sleep=off` the virtual clock then jumps
    /// straight to the next SysTick instead of executing an idle loop).
    #[idle]
    fn idle(_cx: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The sampling + torque loop, 10 kHz (the controller's `dt_s`). Board: the ADC
    /// end-of-conversion of the current sample triggered by the PWM timer in the middle of
    /// every other 20 kHz PWM period. QEMU: the same line, pended by SysTick (src/sim).
    #[task(binds = ADC, priority = 3, shared = [ctrl, board], local = [tel_tx, decimation, done: bool = false])]
    fn sample(cx: sample::Context) {
        let t0 = platform::stamp();
        let tel = cx.local.tel_tx;
        let done = cx.local.done;
        let decimation = *cx.local.decimation;
        let mut ctrl = cx.shared.ctrl;
        let mut board = cx.shared.board;
        // Highest priority: these locks are free (no other task of this priority).
        board.lock(|board| {
            board.ack_sample();
            let tick = tm::TICKS.fetch_add(1, Ordering::Relaxed) + 1;
            crate::fault::inject(tick);
            let out = ctrl.lock(|ctrl| {
                let out = ctrl.tick(board);
                while let Some(ev) = ctrl.poll_event() {
                    let settled = matches!(ev, grasp::Event::Settled { .. });
                    send(tel, Msg::Event(ev));
                    if settled {
                        if let Some(t) = board.truth("settled") {
                            send(tel, Msg::Truth(t));
                        }
                    }
                }
                out
            });
            let t_ctrl = platform::stamp();
            tm::record_work(tick, t_ctrl.wrapping_sub(t0));
            if out.estimate_ready && estimate::spawn().is_err() {
                tm::dropped();
            }
            let finished = ctl::finished(out.state);
            if tick % decimation == 0 || finished {
                // Samples are best effort: a full queue keeps its room for events.
                if !tel.is_full() {
                    let _ = tel.try_send(Msg::Sample {
                        tick,
                        theta_a_urad: out.theta_a_urad,
                        torque_unm: out.torque_unm,
                        torque_ref_unm: out.torque_ref_unm,
                        duty: out.duty,
                        state: out.state,
                    });
                }
            }
            board.advance();
            while let Some(p) = board.poll_plant_event() {
                send(tel, Msg::Plant(p));
            }
            // The END report, once. The loop itself goes on: on the board the finger keeps
            // holding (or stays safe); QEMU exits when the telemetry task has logged it.
            if finished && !*done {
                *done = true;
                if let Some(t) = board.truth("end") {
                    send(tel, Msg::Truth(t));
                }
                send(
                    tel,
                    Msg::Done(Done {
                        status: ctl::status(out.state),
                        state: out.state,
                        bridge_safe: board.is_safe(),
                        ticks: tick,
                    }),
                );
            }
        });
        platform::rearm_sampling();
        tm::PREEMPT.fetch_add(platform::stamp().wrapping_sub(t0), Ordering::Relaxed);
    }

    fn send(tel: &mut Sender<'static, Msg, QUEUE>, msg: Msg) {
        if tel.try_send(msg).is_err() {
            tm::dropped();
        }
    }

    /// The estimate: the settled step → `run_estimate` → `deliver`. Preempted by `sample`.
    #[task(priority = 2, shared = [ctrl, board])]
    async fn estimate(cx: estimate::Context) {
        let mut ctrl = cx.shared.ctrl;
        let mut board = cx.shared.board;
        let t0 = platform::stamp();
        let p0 = tm::PREEMPT.load(Ordering::Relaxed);
        let Some(req) = ctrl.lock(|c| c.take_request()) else {
            return;
        };
        let result = ctl::run_estimate(&req);
        let work = platform::stamp()
            .wrapping_sub(t0)
            .wrapping_sub(tm::PREEMPT.load(Ordering::Relaxed).wrapping_sub(p0));
        let _ = tm::record_max(&tm::EST_WORK_MAX, work);
        (&mut ctrl, &mut board).lock(|c, b| c.deliver(b, result));
    }

    #[task(priority = 1)]
    async fn telemetry(_cx: telemetry::Context, mut rx: Receiver<'static, Msg, QUEUE>) {
        while let Ok(msg) = rx.recv().await {
            tm::log(&msg);
            if let Msg::Done(done) = msg {
                platform::finish(done.status);
            }
        }
    }
}
