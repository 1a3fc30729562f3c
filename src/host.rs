//! The host build of the firmware package: the same control path as the QEMU firmware
//! (grasp controller + simulated board, same configuration, same order of tick → plant step
//! → estimate delivery) on the host's ISA, printing the firmware's log lines. `cargo xtask
//! test` compares its estimate with the QEMU run's (same numbers on both ISAs).
//!
//! `finger-fw simulate [--scene NAME|FILE] [--dta N·m] [--estimator two-point|path-fit]`
//! (default: the scene and settings of this build); the options give the reference of a grasp
//! the device-mode firmware ran with those settings.

use grasp::{Controller, TickOutput};
use sim_board::run::{Limits, Observer, Timing};
use sim_board::PlantBoard;

use crate::ctl;

/// One log line of `fmt` (`proto::log`), as a defmt decoder prints the firmware's.
fn line(fmt: &str, args: &[&dyn std::fmt::Display]) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail.
    let _ = proto::log::render(&mut s, fmt, args);
    s
}

/// The truth line of the simulated finger now.
fn truth_line(plant: &plant::Plant, at: &'static str) -> String {
    let t = sim_board::log::TruthLine::of(plant, at);
    line(
        proto::log::TRUTH,
        &[
            &t.at,
            &t.t_us,
            &t.theta_a_urad,
            &t.torque_unm,
            &t.contact,
            &t.k_um,
        ],
    )
}

/// A controller event's line.
fn event_line(ev: &grasp::Event) -> String {
    line(proto::log::EVENT, &[&format_args!("{ev:?}")])
}

/// Prints the firmware's log lines of a run.
struct HostLog<'a> {
    finger: &'a pts::Finger,
    table: Option<&'a ctl::EstimatorTable>,
    /// A sample line every this many ticks.
    decimation: u32,
    /// The rest check's line is out.
    rest_logged: bool,
}

impl Observer<PlantBoard> for HostLog<'_> {
    fn estimate(
        &mut self,
        req: &grasp::EstimateRequest,
        _board: &PlantBoard,
    ) -> Result<grasp::EstimateResult, grasp::EstimateError> {
        ctl::run_estimate_as(self.finger, req, self.table)
    }

    fn event(&mut self, ev: grasp::Event, board: &PlantBoard) {
        println!("{}", event_line(&ev));
        if matches!(ev, grasp::Event::Settled { .. }) {
            println!("{}", truth_line(&board.plant, "settled"));
        }
    }

    fn after_tick(&mut self, n: u64, out: &TickOutput, ctl: &Controller, _board: &PlantBoard) {
        if let (false, Some(r)) = (self.rest_logged, ctl.rest_report()) {
            self.rest_logged = true;
            println!("{}", rest_line(&r));
        }
        // Ticks count from 1, as the firmware's.
        let tick = n + 1;
        if tick % u64::from(self.decimation) == 0 || ctl::finished(out.state) {
            let sample = line(
                proto::log::SAMPLE,
                &[
                    &tick,
                    &out.theta_a_urad,
                    &out.torque_unm,
                    &out.torque_ref_unm,
                    &out.duty,
                    &format_args!("{:?}", out.state),
                ],
            );
            println!("{sample}");
        }
    }

    fn after_advance(&mut self, board: &mut PlantBoard) {
        while let Some(e) = board.plant.poll_event() {
            let p = sim_board::log::PlantEventLine::of(&e);
            let args: [&dyn std::fmt::Display; 6] = [
                &p.kind,
                &p.t_us,
                &p.theta_a_urad,
                &p.torque_unm,
                &p.phalanx,
                &p.k_um,
            ];
            println!("{}", line(proto::log::PLANT, &args));
        }
    }
}

/// Runs one scene to the end; prints the log lines; returns the firmware's exit status.
pub fn simulate(args: &[String]) -> Result<i32, String> {
    let mut name = None;
    let mut settings = ctl::default_settings();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--scene" => name = it.next().cloned(),
            "--dta" => {
                let v = it.next().ok_or("--dta needs a value (N·m)")?;
                let v: f64 = v.parse().map_err(|_| format!("--dta {v}: not a number"))?;
                settings
                    .set(&proto::Param::DeltaTaNm(v), &[])
                    .map_err(|e| format!("--dta: {e:?}"))?;
            }
            "--estimator" => {
                settings.estimator = match it.next().map(String::as_str) {
                    Some("two-point") => proto::Estimator::TwoPoint,
                    Some("path-fit") => proto::Estimator::PathFit,
                    other => {
                        return Err(format!(
                            "--estimator {other:?}: allowed two-point, path-fit"
                        ))
                    }
                }
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    let scene = match &name {
        Some(n) if n.ends_with(".toml") => {
            plant::toml_scene::from_toml_file(std::path::Path::new(n)).map_err(|e| e.to_string())?
        }
        Some(n) => plant::scenes::by_name(n).ok_or_else(|| {
            format!(
                "no scene {n}; built-in: {}",
                plant::scenes::NAMES.join(", ")
            )
        })?,
        None => ctl::scene().ok_or("the build's scene is unknown")?,
    };
    let scene = if name.is_some() {
        ctl::finger_scene(scene)
    } else {
        scene
    };
    let plant = plant::Plant::new(&scene).map_err(|e| format!("scene: {e:?}"))?;
    let cfg = ctl::with_scene_rest_check(
        ctl::config_with(ctl::scene_drive(&scene), &settings),
        &scene,
    );
    let decimation = ctl::decimation(&cfg.drive);
    // The build's table, as the firmware built with the same environment has it.
    let table = ctl::estimator_table(&cfg.finger, &cfg.drive);
    let mut ctrl = ctl::controller(cfg).map_err(|e| format!("config: {e:?}"))?;
    // The same adapter as the QEMU board's, without the interrupt plumbing.
    let mut board = PlantBoard::new(plant);
    println!(
        "BOOT finger={} l2_um={} scene={} board=host dt_us={}",
        crate::config::FINGER_NAME,
        (crate::config::FINGER.l2 * 1e6) as u32,
        name.as_deref().unwrap_or(crate::config::SCENE),
        (cfg.drive.dt_s * 1e6) as u32
    );
    let limits = Limits {
        // Bound: 60 s of simulated time.
        max_ticks: (60.0 / cfg.drive.dt_s) as u64,
        extra_ticks: Some(0),
        // The firmware's order, so that the log matches the QEMU run's.
        timing: Timing::Firmware,
    };
    let mut log = HostLog {
        finger: &cfg.finger,
        table: table.as_ref(),
        decimation,
        rest_logged: false,
    };
    let end = sim_board::run::run(&mut ctrl, &mut board, limits, &mut log);
    if let (true, Some(out)) = (end.finished, end.last) {
        println!("{}", truth_line(&board.plant, "end"));
        println!(
            "END status={} state={:?} bridge_safe={} ticks={}",
            ctl::status(out.state),
            out.state,
            board.is_off(),
            end.ticks
        );
        return Ok(ctl::status(out.state));
    }
    println!("END status=3 state={:?} timeout", ctrl.state());
    Ok(3)
}

/// The rest check's report, as the firmware logs it (`REST ...`).
pub fn rest_line(r: &grasp::RestReport) -> String {
    format!(
        "REST power_up_urad={} stop_ticks={} done_ticks={}",
        r.power_up_urad, r.stop_ticks, r.done_ticks
    )
}
