//! `pts`: evaluate the PTS finger model, simulate grasps, replay recorded grasps, plot.

use clap::{Parser, Subcommand};
use pts_cli::eval::{Evaluator, Numeric};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

/// Proprioceptive tactile sensing for an underactuated finger: model, simulation, replay, plots.
#[derive(Parser)]
#[command(name = "pts", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Batch evaluator for scripts: one JSON request per line on stdin, one answer per line on stdout.
    ///
    /// SI units. Any request may add "K1"/"K2" (N·m/rad) to override the joint springs and an
    /// "id" that is echoed back. Requests → answers:
    ///
    ///   {"op":"closure","theta1","theta2"} → gamma, theta_a, x2, dx2
    ///   {"op":"kc","theta1","theta2","ta","phalanx":1|2,"k"} → kc
    ///   {"op":"free","ta"} → theta1, theta2, theta_a, kc
    ///   {"op":"invert","theta1","theta2","ta","kc"} → phalanx none|proximal|distal, k2|null
    ///   {"op":"estimate","theta_a_c","ta_c","theta_a","ta"} → kc_hat, phalanx, k2, theta1_c, theta2_c
    ///   {"op":"path","theta1_c","phalanx":1|2,"k_c","radius","dta"} → theta_a_c, ta_c, theta_a, k, dtheta_a
    ///
    /// A line that cannot be answered gets {"ok":false,"error":"<kind>","message":…} and the
    /// stream goes on; the exit status is 0 unless stdin or stdout fail. "path" is the plant's
    /// independent f64 solver whatever --numeric says.
    #[command(verbatim_doc_comment)]
    Eval {
        /// Finger description (TOML); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// Numeric back end.
        #[arg(long, value_enum, default_value = "f64")]
        numeric: Numeric,
    },
    /// Run the grasp controller closed loop against the simulated finger; print events and the
    /// estimate against the truth. With --sweep, a grid of objects × ΔT_a and its error table.
    ///
    /// Exit status: 0 when the grasp produced an estimate (with --sweep: when the grid ran);
    /// 1 when it ended in a fault, the estimator refused it, or on a usage or input error.
    Sim(SimArgs),
    /// Replay a recorded grasp (CSV) through the controller and estimator the firmware runs.
    ///
    /// The CSV needs a header with at least t_s,theta_a_rad,torque_nm (or current_a instead of
    /// torque_nm); other columns are ignored. Prints the contact found: time, phalanx, k2,
    /// K̂c, ΔT_a, Δθa and any fault.
    ///
    /// Exit status: 0 when at least one contact produced an estimate; 1 when none did (no
    /// contact found, every contact refused, a fault) or on a usage or input error. The report
    /// (human or --json) is printed either way.
    Estimate {
        /// The recorded grasp (CSV).
        #[arg(long)]
        trace: PathBuf,
        /// Finger description (TOML); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// The controller's torque step ΔT_a (N·m); default: from the `# pts-sim` line of the
        /// trace, else 0.2.
        #[arg(long)]
        dta: Option<f64>,
        /// Control period (s); default: from the trace.
        #[arg(long)]
        dt_s: Option<f64>,
        /// Machine-readable output: one JSON object, also when the recording cannot be read
        /// at all (`{"trace", "error": {"kind", "message"}}`).
        #[arg(long)]
        json: bool,
        /// The estimator. Default: the path fit on a recording (the two-point estimate is
        /// reported beside it); on a `pts sim` trace, the method `pts sim` defaults to.
        #[arg(long, value_enum)]
        method: Option<pts_cli::method::Method>,
        /// Added to every row's θa (rad) of a recording before it is read, within ±2π: for an
        /// encoder zeroed elsewhere than the finger's model angle (one zeroed at rest: the
        /// file's rest angle, which `pts estimate` names when it refuses the recording's rest).
        #[arg(long, allow_hyphen_values = true)]
        theta_a_offset: Option<f64>,
    },
    /// Turn a decoded defmt log (text) into a trace CSV for `pts estimate` and `pts plot`.
    Trace {
        /// The decoded defmt log (text, one message per line); `-` for stdin.
        #[arg(long = "from-defmt")]
        from_defmt: PathBuf,
        /// Output CSV; default: stdout.
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Finger description (for current → torque); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// Control period (s) for `tick=` times; default: the log's BOOT line, else 1e-4.
        #[arg(long)]
        dt_s: Option<f64>,
    },
    /// Figures as PNG or SVG (by the extension of --out).
    Plot {
        #[command(subcommand)]
        what: PlotCmd,
    },
    /// Identify a finger's springs, rest angles, friction, inertia and torque offset from a
    /// calibration sweep; print each with its σ and the residual, and write the calibrated
    /// finger file. With --simulate, record the sweep(s) on the simulated finger instead.
    ///
    /// A free sweep alone cannot separate K1 from K2 nor see θ0,1: add --touch, a second
    /// sweep against a fixed post on the proximal phalanx at a known θ1; θ0,2 needs
    /// --tip-touch, the free finger closing onto a known point that the distal phalanx meets.
    Calibrate(CalibrateArgs),
    /// Talk to the finger's firmware (the QEMU build's UART socket) in the device protocol.
    ///
    /// Exit status 0 when the device did what was asked; 1 on a refusal (the message names
    /// the value and its allowed range for a bad value), a timeout or a link error; for
    /// `grasp`, 2 when the grasp ended in a fault and 3 when it was stopped.
    Board(BoardArgs),
    /// Print the finger description (every key), e.g. as a template for a new finger.
    Finger {
        /// Finger description to check and print; default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
    },
}

#[derive(clap::Args)]
struct BoardArgs {
    /// The device: HOST:PORT (QEMU's `-serial tcp:HOST:PORT,server=on,wait=off`) or a serial
    /// device path (/dev/ttyACM0, COM3).
    #[arg(long, default_value = "127.0.0.1:4321")]
    connect: String,
    /// Seconds to wait for a reply (a grasp: for its end, see --grasp-timeout).
    #[arg(long, default_value = "5")]
    timeout: f64,
    /// Machine-readable output (one JSON object per reply).
    #[arg(long)]
    json: bool,
    #[command(subcommand)]
    cmd: BoardCmd,
}

#[derive(Subcommand)]
enum BoardCmd {
    /// Protocol version exchange; prints firmware and board.
    Hello,
    /// State, settings and counters.
    Status,
    /// One parameter (delta_ta_nm, step_ramp_nm_per_s, estimator, approach_speed_rad_s,
    /// approach_max_nm, telemetry_hz, seating, scene).
    Get {
        /// Parameter name.
        name: String,
    },
    /// Set a parameter (idle only): `set delta_ta_nm 0.6`, `set estimator path-fit`,
    /// `set step_ramp_nm_per_s step`, `set seating on`, `set scene cyl10_k2_20`.
    Set {
        /// Parameter name.
        name: String,
        /// Value (the parameter's unit).
        value: String,
    },
    /// Close on the object; prints the contact estimate (waits for it unless --no-wait).
    Grasp {
        /// Return once the device accepted the command.
        #[arg(long)]
        no_wait: bool,
        /// Seconds to wait for the grasp's end.
        #[arg(long, default_value = "300")]
        grasp_timeout: f64,
    },
    /// Record one grasp at the control rate (one row per tick, raw encoder and ADC readings)
    /// into a CSV that `pts estimate --trace` replays to the firmware's answer.
    Record {
        /// Output CSV.
        #[arg(short, long)]
        output: std::path::PathBuf,
        /// Seconds to wait for the grasp's end.
        #[arg(long, default_value = "300")]
        grasp_timeout: f64,
    },
    /// The drive constants and control period the firmware converts readings with.
    Drive,
    /// θa, T_a, the live K̂c and the state drawn in the terminal as they arrive (`q` quits);
    /// one summary line per half second when stdout is not a terminal.
    Watch {
        /// Start a grasp and stop watching at its end.
        #[arg(long)]
        grasp: bool,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<f64>,
        /// Telemetry rate while watching (Hz, 1..=10000); the previous rate is restored after.
        #[arg(long, default_value = "200")]
        rate: u16,
        /// Seconds of samples on the charts.
        #[arg(long, default_value = "10")]
        window: f64,
    },
    /// Let go: the torque ramps down and the finger opens back to rest, then idle (waits for
    /// it unless --no-wait). Outside holding it switches the torque off.
    Release {
        /// Return once the device accepted the command.
        #[arg(long)]
        no_wait: bool,
        /// Seconds to wait for the finger to be back and idle.
        #[arg(long, default_value = "60")]
        release_timeout: f64,
    },
    /// Torque off now, from any state; acknowledges a latched fault.
    Stop,
    /// Run the device's calibration sweep (the finger must be free: no object), record it and
    /// identify the finger from it, as `pts calibrate --trace` does from the same file.
    Calibrate {
        /// Where to write the recorded sweep (CSV, `pts calibrate --trace` reads it).
        #[arg(long, required_unless_present = "no_wait")]
        trace: Option<PathBuf>,
        /// Return once the device accepted the command (no recording, no identification).
        #[arg(long)]
        no_wait: bool,
        /// The finger file the firmware was built with (the nominal); default: the paper's
        /// prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// Write the calibrated finger file here.
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// Seconds to wait for the sweep's end.
        #[arg(long, default_value = "300")]
        sweep_timeout: f64,
    },
    /// Store the settings in flash.
    Store,
    /// Load the stored settings.
    Load,
    /// Reset the firmware (bridge off first); stored settings apply after it.
    Reboot,
    /// Send raw bytes (hex) and print whatever comes back within the timeout (protocol tests).
    #[command(hide = true)]
    Raw {
        /// Bytes in hex, e.g. 0102ff00.
        hex: String,
    },
}

#[derive(clap::Args)]
struct SimArgs {
    /// Built-in scene name (see --list) or a scene TOML file (crates/plant/scenes/).
    #[arg(long, default_value = "table2")]
    scene: String,
    /// List the built-in scenes and exit.
    #[arg(long)]
    list: bool,
    /// Torque step after contact ΔT_a (N·m); a list with --sweep. The default is the firmware's.
    /// With --seating a 0.2 N·m step mostly lies inside the realistic drive's stiction band once
    /// the contact is seated, and ends in the fault no_motion.
    #[arg(long, value_delimiter = ',', default_value = "0.8")]
    dta: Vec<f64>,
    /// Write every control tick to this CSV (input of `pts estimate` and `pts plot signals`).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Also draw the grasp signals (or, with --sweep, the error heat map) to this .png/.svg.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Machine-readable output (one JSON object).
    #[arg(long)]
    json: bool,
    /// Simulated time limit per grasp (s).
    #[arg(long, default_value = "10")]
    max_s: f64,
    /// Run a grid: every object radius × contact location × ΔT_a on the Table 2 approach.
    #[arg(long)]
    sweep: bool,
    /// Sweep: object radii (cm; 0 = a vertex).
    #[arg(long, value_delimiter = ',', default_value = "0,1,5")]
    radii_cm: Vec<f64>,
    /// Sweep: contact locations on the distal phalanx (% of l2).
    #[arg(long, value_delimiter = ',', default_value = "10,30,50,70,90")]
    k2_pct: Vec<f64>,
    /// Sweep: use the ideal drive and sensors (no friction, backlash, noise).
    #[arg(long)]
    ideal: bool,
    /// The estimator the controller runs on the settled step (the path fit reports the
    /// two-point k2 beside it).
    #[arg(long, value_enum, default_value = "path-fit")]
    method: pts_cli::method::Method,
    /// Finger description (TOML): the simulated finger and the controller are both built from
    /// it (geometry, springs, drive constants, current limit); default: the scene's finger.
    #[arg(long)]
    finger: Option<PathBuf>,
    /// How ΔT_a is applied: ramp rates (N·m/s, 0 = one step); default: the controller's
    /// (4 N·m/s). A sweep runs each and ends with the time to know against the error.
    #[arg(long, value_delimiter = ',')]
    step_ramp: Vec<f64>,
    /// Seat the contact in static stages before the step (the two-point method's static
    /// points), as `pts board set seating on` does: known about 1.3 s later than the
    /// default, which steps at once from the contact's detection (see docs/RESULTS.md,
    /// "Time to know").
    #[arg(long, conflicts_with = "no_seating")]
    seating: bool,
    /// Step at once from the contact's detection, without the seating stages (the default).
    #[arg(long)]
    no_seating: bool,
}

#[derive(clap::Args)]
struct CalibrateArgs {
    /// The free close-and-open sweep (CSV; written with --simulate).
    #[arg(long)]
    trace: PathBuf,
    /// The sweep against the post (CSV; written with --simulate).
    #[arg(long)]
    touch: Option<PathBuf>,
    /// The free finger closing onto a post that the distal phalanx meets (CSV, with a
    /// `# pts-calibrate tip_post_x_m=… tip_post_y_m=…` line; written with --simulate):
    /// identifies θ0,2, which the other two recordings cannot.
    #[arg(long)]
    tip_touch: Option<PathBuf>,
    /// θ1 at which the proximal phalanx reaches the post (rad); default: the touch trace's
    /// `# pts-calibrate` line (with --simulate: θ0,1 + 0.45 of the file).
    #[arg(long)]
    post_theta1_rad: Option<f64>,
    /// Distance of the post from O1 (m); default: the touch trace's line, else 0.7·l1.
    #[arg(long)]
    post_k1_m: Option<f64>,
    /// The nominal finger file the sweep was recorded with; default: the paper's prototype.
    #[arg(long)]
    finger: Option<PathBuf>,
    /// Write the calibrated finger file here.
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Machine-readable output (one JSON object).
    #[arg(long)]
    json: bool,
    /// Record the sweep(s) on the simulated finger (built from --finger and --perturb) and
    /// write them to --trace (and --touch) instead of identifying.
    #[arg(long)]
    simulate: bool,
    /// With --simulate: the plant's difference from the file, e.g.
    /// k1=1.25,k2=0.75,theta01_deg=3,theta02_deg=-3,friction=2,inertia=3.
    #[arg(long, default_value = "")]
    perturb: String,
    /// With --simulate: the sweep's largest torque (N·m), in (0, 1.5].
    #[arg(long, default_value = "0.6")]
    safe_torque: f64,
    /// With --simulate: write the plant's true finger file here.
    #[arg(long)]
    truth_out: Option<PathBuf>,
    /// With --simulate: run the firmware's sweep (grasp::calibrate, the firmware's sensors and
    /// torque loop) instead of the plant's ideal current ramp.
    #[arg(long)]
    firmware: bool,
}

#[derive(Subcommand)]
enum PlotCmd {
    /// A grasp over time (θa, T_a, running K̂c, controller state), like the paper's Figs. 5 and 9.
    ///
    /// The trace is replayed through the firmware's controller to find the contact and the
    /// estimate it would make.
    Signals {
        /// The recorded grasp (CSV, as written by `pts sim --csv` or `pts trace`).
        #[arg(long)]
        trace: PathBuf,
        /// Finger description (TOML); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// ΔT_a of the controller (N·m); default: from the trace, else 0.2.
        #[arg(long)]
        dta: Option<f64>,
        /// The estimator the controller runs on the settled step.
        #[arg(long, value_enum, default_value = "path-fit")]
        method: pts_cli::method::Method,
        /// Start of the time window (s); e.g. shortly before contact.
        #[arg(long)]
        from_s: Option<f64>,
        /// End of the time window (s).
        #[arg(long)]
        to_s: Option<f64>,
        /// Output file (.png or .svg).
        #[arg(long, short)]
        out: PathBuf,
        /// Image size in px, WIDTHxHEIGHT.
        #[arg(long, default_value = "1200x900")]
        size: pts_cli::plot::Size,
    },
    /// The error table of `pts sim --sweep --json` as a heat map.
    Heat {
        /// The JSON written by `pts sim --sweep --json`.
        #[arg(long)]
        sweep: PathBuf,
        /// Top of the colour scale (% of l2), to compare several maps; default: the largest cell.
        #[arg(long)]
        max: Option<f64>,
        /// Output file (.png or .svg).
        #[arg(long, short)]
        out: PathBuf,
        /// Image size in px, WIDTHxHEIGHT.
        #[arg(long, default_value = "1000x700")]
        size: pts_cli::plot::Size,
    },
    /// K_c(k2) along the distal phalanx at free-motion contact configurations.
    Kc {
        /// Finger description (TOML); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// θ1 at contact (rad), one curve each; default: the paper's Table 2 (1.2797).
        #[arg(long = "theta1-c", value_delimiter = ',', default_value = "1.2797")]
        theta1_c: Vec<f64>,
        /// Mark a measured K̂c (N·m/rad) and where it inverts to on the first curve.
        #[arg(long)]
        mark_kc: Option<f64>,
        /// Output file (.png or .svg).
        #[arg(long, short)]
        out: PathBuf,
        /// Image size in px, WIDTHxHEIGHT.
        #[arg(long, default_value = "1200x800")]
        size: pts_cli::plot::Size,
    },
}

fn run_board(a: BoardArgs) -> ExitCode {
    use pts_cli::board::{Board, BoardError};
    let timeout = wait_limit(a.timeout);
    let json = a.json;
    let mut b = match Board::connect(&a.connect, timeout) {
        Ok(b) => b,
        Err(e) => return board_fail(json, e),
    };
    let cmd = match a.cmd {
        BoardCmd::Hello => proto::Command::Hello {
            version: proto::VERSION,
        },
        BoardCmd::Status => proto::Command::Status,
        BoardCmd::Get { name } => match proto::ParamId::from_name(&name) {
            Some(id) => proto::Command::Get(id),
            None => return board_fail(json, BoardError::Io(format!("no parameter {name}"))),
        },
        BoardCmd::Set { name, value } => match pts_cli::board::parse_param(&name, &value) {
            Ok(p) => proto::Command::Set(p),
            Err(e) => {
                eprintln!("pts board: {e}");
                return ExitCode::FAILURE;
            }
        },
        BoardCmd::Grasp { no_wait: true, .. } => proto::Command::Grasp,
        BoardCmd::Grasp { grasp_timeout, .. } => {
            return board_grasp(&mut b, json, wait_limit(grasp_timeout))
        }
        BoardCmd::Record {
            output,
            grasp_timeout,
        } => return board_record(&mut b, json, &output, wait_limit(grasp_timeout)),
        BoardCmd::Drive => proto::Command::Drive,
        BoardCmd::Watch {
            grasp,
            seconds,
            rate,
            window,
        } => return board_watch(&mut b, json, grasp, seconds, rate, window),
        BoardCmd::Release { no_wait: true, .. } => proto::Command::Release,
        BoardCmd::Release {
            release_timeout, ..
        } => return board_release(&mut b, json, wait_limit(release_timeout)),
        BoardCmd::Stop => proto::Command::Stop,
        BoardCmd::Calibrate {
            trace,
            no_wait,
            finger,
            out,
            sweep_timeout,
        } => match trace.filter(|_| !no_wait) {
            None => proto::Command::Calibrate,
            Some(trace) => {
                return board_calibrate(
                    &mut b,
                    &a.connect,
                    json,
                    &trace,
                    finger,
                    out,
                    sweep_timeout,
                )
            }
        },
        BoardCmd::Store => proto::Command::Store,
        BoardCmd::Load => proto::Command::Load,
        BoardCmd::Reboot => proto::Command::Reboot,
        BoardCmd::Raw { hex } => return board_raw(&mut b, json, &hex, timeout),
    };
    match b.request(cmd) {
        Ok(r) => {
            board_show(json, &r);
            ExitCode::SUCCESS
        }
        Err(e) => board_fail(json, e),
    }
}

/// A `pts board` failure: the error on stderr (and as JSON on stdout with `--json`), exit 1.
fn board_fail(json: bool, e: pts_cli::board::BoardError) -> ExitCode {
    if json {
        println!(
            "{}",
            serde_json::json!({"ok": false, "error": e.to_string()})
        );
    }
    eprintln!("pts board: {e}");
    ExitCode::FAILURE
}

/// One reply or result on stdout, as text or JSON.
fn board_show(json: bool, v: &dyn erased::Show) {
    if json {
        println!("{}", v.json());
    } else {
        println!("{}", v.text());
    }
}

/// The documented exit status of a grasp's outcome: 0 contact, 2 fault, 3 stopped.
fn outcome_code(o: &pts_cli::board::Outcome) -> ExitCode {
    use pts_cli::board::Outcome;
    match o {
        Outcome::Contact(_) => ExitCode::SUCCESS,
        Outcome::Fault(_) => ExitCode::from(2),
        Outcome::Stopped => ExitCode::from(3),
    }
}

/// `pts board grasp`: starts a grasp and waits for its contact, fault or stop.
fn board_grasp(
    b: &mut pts_cli::board::Board,
    json: bool,
    give_up: std::time::Duration,
) -> ExitCode {
    match b.grasp(give_up) {
        Ok(o) => {
            board_show(json, &o);
            outcome_code(&o)
        }
        Err(e) => board_fail(json, e),
    }
}

/// `pts board record`: one grasp at every control tick, written as a trace CSV.
fn board_record(
    b: &mut pts_cli::board::Board,
    json: bool,
    output: &std::path::Path,
    give_up: std::time::Duration,
) -> ExitCode {
    let rec = match b.record(give_up) {
        Ok(r) => r,
        Err(e) => return board_fail(json, e),
    };
    let written = std::fs::File::create(output).and_then(|f| {
        let mut w = std::io::BufWriter::new(f);
        rec.write_csv(&mut w)?;
        std::io::Write::flush(&mut w)
    });
    if let Err(e) = written {
        eprintln!("pts board record: writing {}: {e}", output.display());
        return ExitCode::FAILURE;
    }
    eprintln!(
        "wrote {} ({} ticks at {} s)",
        output.display(),
        rec.samples.len(),
        rec.drive.dt_s
    );
    board_show(json, &rec.outcome);
    outcome_code(&rec.outcome)
}

/// `pts board watch`: the live view (a terminal UI on a terminal, summary lines otherwise).
fn board_watch(
    b: &mut pts_cli::board::Board,
    json: bool,
    grasp: bool,
    seconds: Option<f64>,
    rate: u16,
    window: f64,
) -> ExitCode {
    if !((1..=10_000).contains(&rate) && window > 0.0 && window <= 3600.0) {
        eprintln!(
            "pts board watch: --rate {rate} must be in 1..=10000 Hz and --window {window} in (0, 3600] s"
        );
        return ExitCode::FAILURE;
    }
    let o = pts_cli::watch::WatchOptions {
        grasp,
        seconds: seconds.filter(|s| s.is_finite() && *s > 0.0),
        rate_hz: rate,
        window_s: window,
        json,
    };
    use std::io::IsTerminal;
    let tty = std::io::stdout().is_terminal() && !json;
    match pts_cli::watch::run(b, &o, tty) {
        Ok(w) => {
            match (&w.estimate, w.state) {
                (Some(c), _) if json => {
                    println!("{}", serde_json::json!({"ok": true, "contact": c}))
                }
                (_, Some(proto::DeviceState::Fault(f))) if json => {
                    println!("{}", serde_json::json!({"ok": false, "fault": f}))
                }
                _ if json => println!("{}", serde_json::json!({"ok": true})),
                _ => println!("{}", w.summary()),
            }
            match w.state {
                Some(proto::DeviceState::Fault(_)) => ExitCode::from(2),
                _ => ExitCode::SUCCESS,
            }
        }
        Err(e) => board_fail(json, e),
    }
}

/// `pts board release`: torque off and wait for the finger to open.
fn board_release(
    b: &mut pts_cli::board::Board,
    json: bool,
    give_up: std::time::Duration,
) -> ExitCode {
    match b.release(give_up) {
        Ok(r) => {
            if json {
                println!(
                    "{}",
                    serde_json::json!({"ok": true, "released": {
                        "state": r.state,
                        "theta_a_urad": r.theta_a_urad,
                    }})
                );
            } else {
                let theta = r.theta_a_urad.map_or(String::new(), |t| {
                    format!(", θa {:.4} rad", f64::from(t) * 1e-6)
                });
                println!("released: {}{theta}", r.state.name());
            }
            match r.state {
                proto::DeviceState::Fault(_) => ExitCode::from(2),
                _ => ExitCode::SUCCESS,
            }
        }
        Err(e) => board_fail(json, e),
    }
}

/// `pts board raw HEX`: the bytes sent as they are, the first reply shown.
fn board_raw(
    b: &mut pts_cli::board::Board,
    json: bool,
    hex: &str,
    timeout: std::time::Duration,
) -> ExitCode {
    use pts_cli::board::BoardError;
    let bytes: Result<Vec<u8>, _> = (0..hex.len() / 2)
        .map(|i| u8::from_str_radix(hex.get(2 * i..2 * i + 2).unwrap_or("zz"), 16))
        .collect();
    let Ok(bytes) = bytes else {
        eprintln!("pts board raw: {hex}: not hex");
        return ExitCode::FAILURE;
    };
    if let Err(e) = b.write(&bytes) {
        return board_fail(json, e);
    }
    let t0 = std::time::Instant::now();
    while t0.elapsed() < timeout {
        let ms = match b.poll() {
            Ok(ms) => ms,
            Err(e) => return board_fail(json, e),
        };
        for m in ms {
            match m {
                Ok(proto::DeviceMsg::Reply { id, result }) => {
                    board_show(json, &(id, result));
                    return ExitCode::SUCCESS;
                }
                Ok(_) => {}
                Err(e) => return board_fail(json, BoardError::Frame(e)),
            }
        }
    }
    board_fail(json, BoardError::Timeout(timeout))
}

/// `pts board calibrate --trace`: the device's sweep recorded, written and identified.
fn board_calibrate(
    b: &mut pts_cli::board::Board,
    connect: &str,
    json: bool,
    trace: &std::path::Path,
    finger: Option<PathBuf>,
    out: Option<PathBuf>,
    sweep_timeout: f64,
) -> ExitCode {
    use std::time::Duration;
    let nominal = match pts_cli::load_finger(finger.as_deref()) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("pts board calibrate: {e}");
            return ExitCode::FAILURE;
        }
    };
    let give_up = wait_limit(sweep_timeout);
    eprintln!("calibration sweep: closing and opening the free finger…");
    // A line every 2 s: the sweep takes tens of seconds.
    let mut last = std::time::Instant::now();
    let mut progress = |x: &proto::Sample, n: usize| {
        if last.elapsed() >= Duration::from_secs(2) {
            last = std::time::Instant::now();
            eprintln!(
                "  {n} rows, θa {:.3} rad, torque reference {:.3} N·m",
                f64::from(x.theta_a_urad) * 1e-6,
                f64::from(x.torque_ref_unm) * 1e-6
            );
        }
    };
    let rec = match b.sweep(give_up, &mut progress) {
        Ok(r) => r,
        Err(e) => {
            if json {
                println!(
                    "{}",
                    serde_json::json!({"ok": false, "error": e.to_string()})
                );
            }
            eprintln!("pts board: {e}");
            return ExitCode::FAILURE;
        }
    };
    let rows = rec.rows(&nominal);
    let head = format!(
        "# pts-board-calibrate connect={} finger={}",
        connect, nominal.name
    );
    if let Err(e) = pts_cli::calibrate::write_rows(trace, Some(head), &rows) {
        eprintln!("pts board calibrate: {e}");
        return ExitCode::FAILURE;
    }
    eprintln!("wrote {} ({} rows)", trace.display(), rows.len());
    let reported = pts_cli::calibrate::identify(&rows, None, &nominal)
        .map_err(|e| format!("{}: {e}", trace.display()))
        .and_then(|cal| pts_cli::calibrate::report(&cal, trace, out.as_deref(), json));
    match reported {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pts board calibrate: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Text and JSON views of what `pts board` prints.
mod erased {
    use proto::{Error, Reply};
    use pts_cli::board::{describe, Outcome};

    pub trait Show {
        fn json(&self) -> String;
        fn text(&self) -> String;
    }

    impl Show for Reply {
        fn json(&self) -> String {
            serde_json::json!({"ok": true, "reply": self}).to_string()
        }
        fn text(&self) -> String {
            match self {
                Reply::Ack => "ok".into(),
                Reply::Hello {
                    version,
                    firmware,
                    board,
                } => format!("protocol {version}, {firmware} on {board}"),
                Reply::Status(s) => format!(
                    "state {} (bridge {}), tick {}, grasps {}, scene {}\nsettings ({}{}): {}",
                    s.state.name(),
                    if s.bridge_on { "on" } else { "off" },
                    s.tick,
                    s.grasps,
                    s.scene.as_deref().unwrap_or("-"),
                    match s.settings_source {
                        proto::SettingsSource::Store => "from the store".to_string(),
                        proto::SettingsSource::Defaults { why } => format!(
                            "build defaults: {}",
                            pts_cli::board::store_failure_text(why)
                        ),
                    },
                    if s.settings_changed {
                        ", changed since, not stored"
                    } else {
                        ""
                    },
                    pts_cli::board::settings_text(&s.settings)
                ),
                Reply::Param(p) => {
                    let (name, value) = pts_cli::board::param_text(p);
                    format!("{name} {value}")
                }
                Reply::Drive(d) => format!(
                    "control period {} s; gear {} × η {}, kt {} N·m/A, R {} Ω, bus {} V; \
                     {} counts/rev; {} A/code, zero at code {}; θa,rest {} rad",
                    d.dt_s,
                    d.gear_ratio,
                    d.efficiency,
                    d.kt_nm_per_a,
                    d.resistance_ohm,
                    d.bus_v,
                    d.counts_per_rev,
                    d.amps_per_code,
                    d.zero_code,
                    d.theta_a_rest_rad
                ),
            }
        }
    }

    impl Show for (u16, Result<Reply, Error>) {
        fn json(&self) -> String {
            match &self.1 {
                Ok(r) => serde_json::json!({"ok": true, "id": self.0, "reply": r}).to_string(),
                Err(e) => serde_json::json!({"ok": false, "id": self.0, "device_error": e, "error": describe(e)}).to_string(),
            }
        }
        fn text(&self) -> String {
            match &self.1 {
                Ok(r) => r.text(),
                Err(e) => format!("refused: {}", describe(e)),
            }
        }
    }

    impl Show for Outcome {
        fn json(&self) -> String {
            match self {
                Outcome::Contact(c) => serde_json::json!({"ok": true, "contact": c}).to_string(),
                Outcome::Fault(f) => serde_json::json!({"ok": false, "fault": f}).to_string(),
                Outcome::Stopped => serde_json::json!({"ok": false, "stopped": true}).to_string(),
            }
        }
        fn text(&self) -> String {
            match self {
                Outcome::Contact(c) => format!(
                    "grasp {}: {}, ΔT_a {:.3} N·m, Δθa {:.2} mrad",
                    c.grasp,
                    pts_cli::watch::estimate_words(c),
                    f64::from(c.delta_ta_unm) * 1e-6,
                    f64::from(c.delta_theta_a_urad) * 1e-3,
                ),
                Outcome::Fault(f) => format!("fault {:?} (value {}): bridge off", f.kind, f.value),
                Outcome::Stopped => "stopped: bridge off".into(),
            }
        }
    }
}

/// A wait given in seconds on the command line, as a `Duration` (clamped to 10 ms … 1 day:
/// a negative, zero or absurd value is neither a panic nor a wait for ever).
fn wait_limit(s: f64) -> std::time::Duration {
    std::time::Duration::from_secs_f64(s.clamp(0.01, 86_400.0))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Eval { finger, numeric } => run_eval(finger, numeric),
        Cmd::Sim(args) => pts_cli::sim_cmd::run(&args.into()),
        Cmd::Estimate {
            trace,
            finger,
            dta,
            dt_s,
            json,
            method,
            theta_a_offset,
        } => pts_cli::estimate_cmd::run(&pts_cli::estimate_cmd::EstimateArgs {
            trace: &trace,
            finger: finger.as_deref(),
            dta,
            dt_s,
            json,
            method,
            theta_a_offset_rad: theta_a_offset,
        }),
        Cmd::Trace {
            from_defmt,
            out,
            finger,
            dt_s,
        } => {
            pts_cli::estimate_cmd::from_defmt(&from_defmt, out.as_deref(), finger.as_deref(), dt_s)
        }
        Cmd::Plot { what } => run_plot(what),
        Cmd::Calibrate(c) => pts_cli::calibrate::run(&pts_cli::calibrate::Args {
            trace: c.trace,
            touch: c.touch,
            tip_touch: c.tip_touch,
            post_theta1_rad: c.post_theta1_rad,
            post_k1_m: c.post_k1_m,
            finger: c.finger,
            out: c.out,
            json: c.json,
            simulate: c.simulate,
            perturb: c.perturb,
            safe_torque_nm: c.safe_torque,
            truth_out: c.truth_out,
            firmware: c.firmware,
        }),
        Cmd::Board(args) => return run_board(args),
        Cmd::Finger { finger } => pts_cli::load_finger(finger.as_deref()).and_then(|f| {
            let derived = pts_cli::finger_derived(&f)?;
            pts_cli::outln!("{}\n\n{derived}", f.to_toml_string().trim_end());
            Ok(())
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(msg) => {
            eprintln!("pts: {msg}");
            ExitCode::FAILURE
        }
    }
}

fn run_eval(finger: Option<PathBuf>, numeric: Numeric) -> Result<(), String> {
    let file = pts_cli::load_finger_model(finger.as_deref())?;
    let ev = Evaluator::new(file.finger, numeric);
    let mut stdin = std::io::stdin().lock();
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut buf = Vec::new();
    while pts_cli::eval::read_line_limited(&mut stdin, &mut buf, pts_cli::eval::LINE_MAX_BYTES)? {
        // A line that is not UTF-8 is a malformed request like any other, not a failed stdin.
        let answer = match std::str::from_utf8(&buf) {
            Ok(line) => ev.eval_line(line),
            Err(_) => ev.not_utf8(),
        };
        writeln!(out, "{answer}").map_err(|e| format!("writing stdout: {e}"))?;
        // Scripts may talk to us line by line through a pipe: answer each line now.
        out.flush().map_err(|e| format!("writing stdout: {e}"))?;
    }
    Ok(())
}

fn run_plot(what: PlotCmd) -> Result<(), String> {
    use pts_cli::plot;
    match what {
        PlotCmd::Kc {
            finger,
            theta1_c,
            mark_kc,
            out,
            size,
        } => {
            let file = pts_cli::load_finger_model(finger.as_deref())?;
            let model = pts::Model::<f64>::new(&file.finger).map_err(|e| e.to_string())?;
            let curves = theta1_c
                .iter()
                .map(|&t| plot::kc_data(&model, t, 300))
                .collect::<Result<Vec<_>, _>>()?;
            let mark = match (mark_kc, theta1_c.first()) {
                (Some(kc), Some(&t1)) => {
                    let ta = file.finger.k1 * (t1 - file.finger.theta01);
                    let mut cfg = model.free_from_torque(ta).map_err(|e| e.to_string())?;
                    cfg.ta = ta;
                    let c = model
                        .invert(&cfg, kc)
                        .map_err(|e| format!("--mark-kc {kc}: {e}"))?;
                    c.k2.map(|k2| plot::KcMark { kc, k2 })
                }
                _ => None,
            };
            let title = format!("K_c(k2) at contact, {}", file.name);
            plot::kc_curve(&out, size, &title, file.finger.l2, &curves, mark)?;
            eprintln!("wrote {}", out.display());
            Ok(())
        }
        PlotCmd::Signals {
            trace,
            finger,
            dta,
            method,
            from_s,
            to_s,
            out,
            size,
        } => pts_cli::estimate_cmd::plot_signals(
            &trace,
            finger.as_deref(),
            dta,
            method,
            (from_s, to_s),
            &out,
            size,
        ),
        PlotCmd::Heat {
            sweep,
            max,
            out,
            size,
        } => pts_cli::sim_cmd::plot_heat(&sweep, &out, size, max),
    }
}

impl From<SimArgs> for pts_cli::sim_cmd::Args {
    fn from(a: SimArgs) -> Self {
        pts_cli::sim_cmd::Args {
            scene: a.scene,
            list: a.list,
            dta: a.dta,
            csv: a.csv,
            plot: a.plot,
            json: a.json,
            max_s: a.max_s,
            sweep: a.sweep,
            radii_cm: a.radii_cm,
            k2_pct: a.k2_pct,
            ideal: a.ideal,
            method: a.method,
            finger: a.finger,
            step_ramp: a.step_ramp,
            seating: if a.seating {
                Some(true)
            } else {
                a.no_seating.then_some(false)
            },
        }
    }
}
