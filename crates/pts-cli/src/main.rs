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
    /// Print the finger description (every key), e.g. as a template for a new finger.
    Finger {
        /// Finger description to check and print; default: the paper's prototype.
        #[arg(long)]
        finger: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Eval { finger, numeric } => run_eval(finger, numeric),
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
