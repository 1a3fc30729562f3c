//! `pts`: evaluate the PTS finger model, simulate grasps, replay recorded grasps, plot.

use clap::{Parser, Subcommand};
use pts_cli::eval::{Evaluator, Numeric};
use std::io::{BufRead, Write};
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
    /// Ops: closure, kc, free, invert, estimate, path. SI units. "K1"/"K2" override the springs.
    Eval {
        /// Finger description (TOML); default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
        /// Numeric back end.
        #[arg(long, value_enum, default_value = "f64")]
        numeric: Numeric,
    },
    /// Figures as PNG or SVG (by the extension of --out).
    Plot {
        #[command(subcommand)]
        what: PlotCmd,
    },
    /// Print the finger description (every key), e.g. as a template for a new finger.
    Finger {
        /// Finger description to check and print; default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum PlotCmd {
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Eval { finger, numeric } => run_eval(finger, numeric),
        Cmd::Plot { what } => run_plot(what),
        Cmd::Finger { finger } => {
            pts_cli::load_finger(finger.as_deref()).map(|f| print!("{}", f.to_toml_string()))
        }
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
    let file = pts_cli::load_finger(finger.as_deref())?;
    let ev = Evaluator::new(file.finger, numeric);
    let stdin = std::io::stdin().lock();
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    for line in stdin.lines() {
        let line = line.map_err(|e| format!("reading stdin: {e}"))?;
        writeln!(out, "{}", ev.eval_line(&line)).map_err(|e| format!("writing stdout: {e}"))?;
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
            let file = pts_cli::load_finger(finger.as_deref())?;
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
    }
}
