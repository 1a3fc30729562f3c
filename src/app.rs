//! The RTIC application: three priorities, one job each.
//!
//! | prio | task        | kind                      | work                                             |
//! |------|-------------|---------------------------|--------------------------------------------------|
//! | 3    | `sample`    | hardware (ADC EOC; QEMU: pended by SysTick), 1 kHz | read encoder + current, `Controller::tick`, set the duty; forward the estimate request and events |
//! | 2    | `estimate`  | software (async)          | `run_estimate` on the settled step, `deliver` it |
//! | 1    | `telemetry` | software (async)          | defmt: every event, θa/T_a/state decimated ×20   |
//!
//! The control task never waits: it hands data on with `try_send` and counts what a full
//! queue drops. The controller is the only shared resource (the estimate task locks it for
//! `deliver`, a few dozen instructions).

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

    use rtic_sync::channel::{Receiver, Sender};
    use rtic_sync::make_channel;

    use crate::ctl::{self, Controller, EstimateRequest, Hardware};
    use crate::platform::{self, Board};
    use crate::telemetry::{self as tm, Done, Msg, DECIMATION, QUEUE};

    const EST_QUEUE: usize = 2;

    #[shared]
    struct Shared {
        ctrl: Controller,
    }

    #[local]
    struct Local {
        board: Board,
        est_tx: Sender<'static, EstimateRequest, EST_QUEUE>,
        tel_tx: Sender<'static, Msg, QUEUE>,
        tel_tx_est: Sender<'static, Msg, QUEUE>,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let (est_tx, est_rx) = make_channel!(EstimateRequest, EST_QUEUE);
        let (tel_tx, tel_rx) = make_channel!(Msg, QUEUE);
        let tel_tx_est = tel_tx.clone();
        #[cfg(feature = "qemu")]
        let board = platform::init(cx.core);
        #[cfg(not(feature = "qemu"))]
        let board = platform::init(cx.core, cx.device);
        defmt::info!(
            "BOOT finger={=str} scene={=str} board={=str}",
            crate::config::FINGER_NAME,
            crate::config::SCENE,
            platform::NAME
        );
        estimate::spawn(est_rx).ok();
        telemetry::spawn(tel_rx).ok();
        (
            Shared {
                ctrl: ctl::new_controller(),
            },
            Local {
                board,
                est_tx,
                tel_tx,
                tel_tx_est,
            },
        )
    }

    /// The sampling + torque loop, 1 kHz. Board: the ADC end-of-conversion interrupt of the
    /// current sample triggered by the PWM timer at the centre of every 20th PWM period.
    /// QEMU: the same interrupt line, pended by SysTick (src/sim).
    #[task(binds = ADC, priority = 3, shared = [ctrl], local = [board, est_tx, tel_tx, done: bool = false])]
    fn sample(cx: sample::Context) {
        let l = cx.local;
        sample_body(cx.shared.ctrl, l.board, l.est_tx, l.tel_tx, l.done);
    }

    /// One control period (both boards).
    fn sample_body(
        mut ctrl: impl rtic::Mutex<T = Controller>,
        board: &mut Board,
        est: &mut Sender<'static, EstimateRequest, EST_QUEUE>,
        tel: &mut Sender<'static, Msg, QUEUE>,
        done: &mut bool,
    ) {
        board.ack_sample();
        if *done {
            board.bridge_off();
            platform::stop_sampling();
            return;
        }
        let tick = tm::TICKS.fetch_add(1, Ordering::Relaxed) + 1;
        let (out, finished) = ctrl.lock(|ctrl| {
            let out = ctrl.tick(board);
            while let Some(ev) = ctrl.poll_event() {
                if tel.try_send(Msg::Event(ev)).is_err() {
                    tm::dropped();
                }
            }
            (out, ctl::finished(ctrl.state()))
        });
        if let Some(req) = out.estimate_request {
            if est.try_send(req).is_err() {
                tm::dropped();
            }
        }
        if tick % DECIMATION == 0 || finished {
            // Samples are best effort: a full queue keeps its room for events.
            let _ = tel.try_send(Msg::Sample {
                tick,
                theta_a_urad: out.theta_a_urad,
                ta_unm: out.ta_unm,
                state: out.state,
            });
        }
        board.advance();
        if finished {
            *done = true;
            board.bridge_off();
            let done = Done {
                status: if out.state == ctl::State::Fault { 2 } else { 0 },
                state: out.state,
                bridge_safe: board.is_safe(),
                truth_theta_a_urad: board.truth_theta_a_urad(),
                t_us: tick.saturating_mul(1000),
            };
            if tel.try_send(Msg::Done(done)).is_err() {
                tm::dropped();
            }
        }
        platform::rearm_sampling();
    }

    #[task(priority = 2, shared = [ctrl], local = [tel_tx_est])]
    async fn estimate(
        mut cx: estimate::Context,
        mut rx: Receiver<'static, EstimateRequest, EST_QUEUE>,
    ) {
        while let Ok(req) = rx.recv().await {
            let result = ctl::run_estimate(&req);
            cx.shared.ctrl.lock(|ctrl| ctrl.deliver(result));
        }
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
