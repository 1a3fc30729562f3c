//! `cargo xtask figures [--check]`: every figure the documentation shows, drawn by `pts` from
//! the code as it is now. `--check` draws them into a scratch directory and compares them with
//! the committed files, so a figure cannot go stale unnoticed (a stage of `cargo xtask test`).

use std::path::{Path, PathBuf};

use crate::util::{self, Res};

/// Where the documented figures live, from the repository root.
pub const DIR: &str = "docs/figures";

/// One documented figure: its file name and the `pts` invocations that draw it. `{out}` is the
/// figure's path, `{tmp}` a scratch directory shared by the steps of one figure.
struct Figure {
    file: &'static str,
    steps: &'static [&'static [&'static str]],
}

/// The sweep every heat map shows: objects × ΔT_a, five contact locations each.
const SWEEP: &[&str] = &[
    "sim",
    "--sweep",
    "--dta",
    "0.1,0.2,0.4,0.8",
    "--radii-cm",
    "0,1,5,9.75",
    "--json",
];

/// The heat map of the sweep a figure's first step wrote, on a common colour scale.
const HEAT: &[&str] = &[
    "plot",
    "heat",
    "--sweep",
    "{tmp}/s.json",
    "--max",
    "40",
    "-o",
    "{out}",
];

const FIGURES: &[Figure] = &[
    Figure {
        file: "kc_k2.svg",
        steps: &[&[
            "plot",
            "kc",
            "--theta1-c",
            "1.2797,1.0,1.6",
            "--mark-kc",
            "9.965",
            "-o",
            "{out}",
        ]],
    },
    Figure {
        file: "grasp_table2.svg",
        steps: &[
            &[
                "sim",
                "--scene",
                "table2",
                "--dta",
                "0.8",
                "--method",
                "two-point",
                "--csv",
                "{tmp}/t2.csv",
            ],
            &[
                "plot",
                "signals",
                "--trace",
                "{tmp}/t2.csv",
                "--method",
                "two-point",
                "--from-s",
                "3.9",
                "-o",
                "{out}",
            ],
        ],
    },
    Figure {
        file: "grasp_table2_pathfit.svg",
        steps: &[
            &[
                "sim",
                "--scene",
                "table2",
                "--dta",
                "0.8",
                "--method",
                "path-fit",
                "--csv",
                "{tmp}/t2.csv",
            ],
            &[
                "plot",
                "signals",
                "--trace",
                "{tmp}/t2.csv",
                "--method",
                "path-fit",
                "--from-s",
                "3.9",
                "-o",
                "{out}",
            ],
        ],
    },
    Figure {
        file: "sweep_two-point.svg",
        steps: &[&["{sweep}", "--method", "two-point", ">{tmp}/s.json"], HEAT],
    },
    Figure {
        file: "sweep_pathfit.svg",
        steps: &[&["{sweep}", "--method", "path-fit", ">{tmp}/s.json"], HEAT],
    },
    Figure {
        file: "sweep_ideal.svg",
        steps: &[
            &[
                "{sweep}",
                "--ideal",
                "--method",
                "two-point",
                ">{tmp}/s.json",
            ],
            HEAT,
        ],
    },
];

/// The words of one step with its placeholders filled; the stdout file when it ends in `>FILE`.
fn expand(step: &[&str], out: &Path, tmp: &Path) -> (Vec<String>, Option<PathBuf>) {
    let fill = |w: &str| {
        w.replace("{out}", &out.to_string_lossy())
            .replace("{tmp}", &tmp.to_string_lossy())
    };
    let mut args = vec![];
    let mut stdout = None;
    for w in step {
        if *w == "{sweep}" {
            args.extend(SWEEP.iter().map(|s| s.to_string()));
        } else if let Some(file) = w.strip_prefix('>') {
            stdout = Some(PathBuf::from(fill(file)));
        } else {
            args.push(fill(w));
        }
    }
    (args, stdout)
}

/// Draws every figure into `dir` with the `pts` binary of xtask's host profile.
fn draw_all(dir: &Path) -> Res {
    let pts = util::build_pts()?;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for (i, fig) in FIGURES.iter().enumerate() {
        eprintln!("[{}/{}] {}", i + 1, FIGURES.len(), fig.file);
        let tmp = std::env::temp_dir().join(format!("xtask-figures-{}-{i}", std::process::id()));
        std::fs::create_dir_all(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
        let out = dir.join(fig.file);
        for step in fig.steps {
            let (args, stdout) = expand(step, &out, &tmp);
            let mut cmd = std::process::Command::new(&pts);
            cmd.args(&args).current_dir(util::root());
            match stdout {
                Some(file) => {
                    let text = util::output(&mut cmd)?;
                    std::fs::write(&file, text).map_err(|e| format!("{}: {e}", file.display()))?;
                }
                None => util::run(cmd.stdout(std::process::Stdio::null()))?,
            }
        }
        let _ = std::fs::remove_dir_all(&tmp);
    }
    Ok(())
}

/// The committed figures that differ from a fresh drawing in `fresh` (or are missing).
fn stale(fresh: &Path) -> Vec<String> {
    let committed = util::root().join(DIR);
    FIGURES
        .iter()
        .filter(|f| {
            std::fs::read(committed.join(f.file)).ok() != std::fs::read(fresh.join(f.file)).ok()
        })
        .map(|f| format!("{DIR}/{}", f.file))
        .collect()
}

/// Entry point of `cargo xtask figures`.
pub fn main(args: &[String]) -> Res<i32> {
    let check = match args {
        [] => false,
        [a] if a == "--check" => true,
        _ => {
            return Err(format!(
                "unexpected arguments {args:?}; usage: cargo xtask figures [--check]"
            ))
        }
    };
    if !check {
        draw_all(&util::root().join(DIR))?;
        eprintln!("wrote {} figures to {DIR}/", FIGURES.len());
        return Ok(0);
    }
    check_current().map(|()| 0)
}

/// `--check`: `Err` naming every figure that is not what the code draws now.
pub fn check_current() -> Res {
    let fresh = std::env::temp_dir().join(format!("xtask-figures-check-{}", std::process::id()));
    draw_all(&fresh)?;
    let bad = stale(&fresh);
    let _ = std::fs::remove_dir_all(&fresh);
    if bad.is_empty() {
        eprintln!("all {} figures in {DIR}/ are current", FIGURES.len());
        Ok(())
    } else {
        Err(format!(
            "stale figure(s), redraw with `cargo xtask figures` and commit: {}",
            bad.join(", ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placeholders_and_redirection_expand() {
        let (args, out) = expand(
            &["{sweep}", "--ideal", ">{tmp}/s.json"],
            Path::new("/o.svg"),
            Path::new("/t"),
        );
        assert_eq!(args[..2], ["sim", "--sweep"]);
        assert_eq!(args.last().map(String::as_str), Some("--ideal"));
        assert_eq!(out, Some(PathBuf::from("/t/s.json")));
        let (args, out) = expand(
            &["plot", "-o", "{out}"],
            Path::new("/o.svg"),
            Path::new("/t"),
        );
        assert_eq!(args, ["plot", "-o", "/o.svg"]);
        assert_eq!(out, None);
    }

    #[test]
    fn every_documented_figure_is_drawn_by_a_recipe() {
        // Each figure the docs embed from docs/figures/ has a recipe here (and so a check).
        let root = util::root();
        let mut docs = String::new();
        for f in [
            "README.md",
            "docs/RESULTS.md",
            "docs/ARCHITECTURE.md",
            "crates/pts-cli/README.md",
        ] {
            docs.push_str(&std::fs::read_to_string(root.join(f)).unwrap_or_default());
        }
        for (i, _) in docs.match_indices("figures/") {
            let name: String = docs[i + "figures/".len()..]
                .chars()
                .take_while(|c| !matches!(c, ')' | ' ' | '"' | '`'))
                .collect();
            if !name.ends_with(".svg") {
                continue; // prose naming the directory, not an embedded figure
            }
            assert!(
                FIGURES.iter().any(|f| f.file == name),
                "docs embed figures/{name}, which no recipe draws"
            );
        }
    }
}
