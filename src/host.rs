//! The host build of the firmware package: the same control path as the QEMU firmware
//! (grasp controller + simulated board, same configuration, same order of tick → plant step
//! → estimate delivery) on the host's ISA, printing the firmware's log lines. `cargo xtask
//! test` compares its estimate with the QEMU run's (same numbers on both ISAs).
//!
//! `finger-fw simulate [--scene NAME|FILE] [--dta N·m] [--estimator two-point|path-fit]`
//! (default: the scene and settings of this build); the options give the reference of a grasp
//! the device-mode firmware ran with those settings.

use grasp::Controller;

use crate::ctl;

/// The TRUTH log line of the simulated finger now (as src/sim prints it).
fn truth_line(plant: &plant::Plant, at: &str) -> String {
    let t = plant.truth();
    format!(
        "TRUTH at={at} t_us={} theta_a_urad={} torque_unm={} contact={} k_um={}",
        (t.t_s * 1e6) as u32,
        micro(t.theta_a_rad),
        micro(t.torque_a_nm),
        t.contact.name(),
        micro(t.k_m)
    )
}

fn micro(v: f64) -> i32 {
    let x = v * 1e6;
    if x.is_nan() {
        0
    } else {
        x.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
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
    let table = ctl::estimator_table(&cfg.finger, cfg.drive.dt_s);
    let mut ctrl = Controller::new(cfg).map_err(|e| format!("config: {e:?}"))?;
    // The same adapter as the QEMU board's, without the interrupt plumbing.
    let mut board = sim_board::PlantBoard::new(plant);
    println!(
        "BOOT finger={} l2_um={} scene={} board=host dt_us={}",
        crate::config::FINGER_NAME,
        (crate::config::FINGER.l2 * 1e6) as u32,
        name.as_deref().unwrap_or(crate::config::SCENE),
        (cfg.drive.dt_s * 1e6) as u32
    );
    // Bound: 60 s of simulated time.
    let max_ticks = (60.0 / cfg.drive.dt_s) as u32;
    let mut rest_logged = false;
    for tick in 1..=max_ticks {
        let out = ctrl.tick(&mut board);
        if let (false, Some(r)) = (rest_logged, ctrl.rest_report()) {
            rest_logged = true;
            println!("{}", rest_line(&r));
        }
        while let Some(ev) = ctrl.poll_event() {
            println!("E {ev:?}");
            if matches!(ev, grasp::Event::Settled { .. }) {
                println!("{}", truth_line(&board.plant, "settled"));
            }
        }
        let finished = ctl::finished(out.state);
        if tick % decimation == 0 || finished {
            println!(
                "S tick={tick} theta_a_urad={} torque_unm={} ref_unm={} duty={} state={:?}",
                out.theta_a_urad, out.torque_unm, out.torque_ref_unm, out.duty, out.state
            );
        }
        board.advance();
        while let Some(e) = board.plant.poll_event() {
            println!("P {} t_us={}", e.kind.name(), (e.t_s * 1e6) as u32);
        }
        if out.estimate_ready {
            if let Some(req) = ctrl.take_request() {
                let result = ctl::run_estimate_as(&cfg.finger, &req, table.as_ref());
                ctrl.deliver(&mut board, result);
                while let Some(ev) = ctrl.poll_event() {
                    println!("E {ev:?}");
                }
            }
        }
        let state = ctrl.state();
        if finished || ctl::finished(state) {
            if !finished {
                continue;
            }
            println!("{}", truth_line(&board.plant, "end"));
            println!(
                "END status={} state={:?} bridge_safe={} ticks={tick}",
                ctl::status(out.state),
                out.state,
                board.is_off()
            );
            return Ok(ctl::status(out.state));
        }
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
