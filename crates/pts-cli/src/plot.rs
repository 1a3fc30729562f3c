//! `pts plot`: figures as PNG or SVG (chosen by the file extension).
//!
//! * [`kc_curve`]: K_c(k2) along the distal phalanx at a free-motion contact configuration,
//!   with the free-motion and proximal-contact levels (log scale: ln K_c is nearly linear in k2).
//! * [`signals`]: a grasp over time (θa, T_a and its reference, the running K̂c = ΔT_a/Δθa
//!   after contact, the controller state as background bands), like the paper's Figs. 5 and 9.
//! * [`heat_map`]: an error table (e.g. the location error of a `pts sim --sweep`).
//!
//! Pure Rust: plotters' bitmap and SVG backends, text rasterized by ab_glyph from the
//! embedded DejaVu Sans, so it runs on a machine without system fonts.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::Once;

/// Image size in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Size {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
}

impl std::str::FromStr for Size {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (w, h) = s
            .split_once(['x', 'X'])
            .ok_or_else(|| format!("size \"{s}\" must look like 1200x800"))?;
        let parse = |v: &str| -> Result<u32, String> {
            v.trim()
                .parse::<u32>()
                .ok()
                .filter(|n| (200..=8000).contains(n))
                .ok_or_else(|| format!("size \"{s}\": each side must be 200..8000 px"))
        };
        Ok(Size {
            width: parse(w)?,
            height: parse(h)?,
        })
    }
}

static FONT: Once = Once::new();

fn fonts() {
    FONT.call_once(|| {
        // Both registrations take static bytes that are valid TrueType: they cannot fail.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

fn err<E: std::fmt::Debug>(e: E) -> String {
    format!("drawing failed: {e:?}")
}

/// Renders with the backend the extension asks for (`.png` or `.svg`).
fn render(
    out: &Path,
    size: Size,
    draw: impl Fn(DrawingArea<BitMapBackend, Shift>) -> Result<(), String>,
    draw_svg: impl Fn(DrawingArea<SVGBackend, Shift>) -> Result<(), String>,
) -> Result<(), String> {
    fonts();
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            return Err(format!("output folder {} does not exist", dir.display()));
        }
    }
    match ext.as_deref() {
        Some("png") => {
            let root = BitMapBackend::new(out, (size.width, size.height)).into_drawing_area();
            root.fill(&WHITE).map_err(err)?;
            draw(root.clone())?;
            root.present()
                .map_err(|e| format!("cannot write {}: {e:?}", out.display()))
        }
        Some("svg") => {
            let root = SVGBackend::new(out, (size.width, size.height)).into_drawing_area();
            root.fill(&WHITE).map_err(err)?;
            draw_svg(root.clone())?;
            root.present()
                .map_err(|e| format!("cannot write {}: {e:?}", out.display()))
        }
        _ => Err(format!(
            "{}: the output must end in .png or .svg",
            out.display()
        )),
    }
}

// ------------------------------------------------------------------------------------ K_c(k2)

/// One K_c(k2) curve at a contact configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct KcCurve {
    /// Legend label.
    pub label: String,
    /// (k2 in m, K_c in N·m/rad) points along the distal phalanx.
    pub points: Vec<(f64, f64)>,
    /// Free-motion stiffness at the configuration (N·m/rad).
    pub kc_free: f64,
    /// Proximal-contact stiffness at the configuration (N·m/rad).
    pub kc_proximal: f64,
}

/// A measured stiffness to mark on the K_c(k2) plot and where it inverts to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KcMark {
    /// K̂c (N·m/rad).
    pub kc: f64,
    /// Its location k2 (m) on the first curve.
    pub k2: f64,
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    PALETTE.get(i % PALETTE.len()).copied().unwrap_or(BLACK)
}

/// Draws K_c(k2) curves (k2 in cm on the x axis, log K_c on y).
pub fn kc_curve(
    out: &Path,
    size: Size,
    title: &str,
    l2_m: f64,
    curves: &[KcCurve],
    mark: Option<KcMark>,
) -> Result<(), String> {
    if curves.iter().all(|c| c.points.is_empty()) {
        return Err("nothing to plot: no curve has a point".into());
    }
    render(
        out,
        size,
        |r| draw_kc(r, title, l2_m, curves, mark),
        |r| draw_kc(r, title, l2_m, curves, mark),
    )
}

fn draw_kc<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    l2_m: f64,
    curves: &[KcCurve],
    mark: Option<KcMark>,
) -> Result<(), String> {
    let all = curves
        .iter()
        .flat_map(|c| {
            c.points
                .iter()
                .map(|p| p.1)
                .chain([c.kc_free, c.kc_proximal])
        })
        .filter(|v| v.is_finite() && *v > 0.0);
    let (lo, hi) = all.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !(lo.is_finite() && hi > 0.0) {
        return Err("nothing to plot: no positive stiffness".into());
    }
    let fs = (root.dim_in_pixel().1 / 40).max(12);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", fs + 6))
        .margin(fs)
        .x_label_area_size(fs * 3)
        .y_label_area_size(fs * 4)
        .build_cartesian_2d(0.0..l2_m * 1e3, (lo * 0.8..hi * 1.25).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("contact location k2 from O2 (mm)")
        .y_desc("K_c at the actuator (N·m/rad), log scale")
        .y_labels(12)
        .y_label_formatter(&|v| format!("{v:.1}"))
        .label_style(("sans-serif", fs))
        .axis_desc_style(("sans-serif", fs + 2))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(err)?;
    for (i, c) in curves.iter().enumerate() {
        let col = color(i);
        chart
            .draw_series(LineSeries::new(
                c.points.iter().map(|&(k, v)| (k * 1e3, v)),
                col.stroke_width(3),
            ))
            .map_err(err)?
            .label(c.label.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], col.stroke_width(3)));
        let dashed = |level: f64| {
            let n = 40;
            (0..n).filter(|j| j % 2 == 0).map(move |j| {
                let a = l2_m * 1e3 * j as f64 / n as f64;
                let b = l2_m * 1e3 * (j + 1) as f64 / n as f64;
                PathElement::new([(a, level), (b, level)], col.mix(0.7).stroke_width(1))
            })
        };
        chart.draw_series(dashed(c.kc_proximal)).map_err(err)?;
        chart.draw_series(dashed(c.kc_free)).map_err(err)?;
        if i == 0 {
            let x = l2_m * 1e3 * 0.62;
            chart
                .draw_series([
                    Text::new(
                        format!("proximal contact (any k1): {:.3}", c.kc_proximal),
                        (x, c.kc_proximal * 1.12),
                        ("sans-serif", fs).into_font().color(&col.mix(0.8)),
                    ),
                    Text::new(
                        format!("free motion (no contact): {:.3}", c.kc_free),
                        (x, c.kc_free * 1.12),
                        ("sans-serif", fs).into_font().color(&col.mix(0.8)),
                    ),
                ])
                .map_err(err)?;
        }
    }
    if let Some(m) = mark {
        let k = m.k2 * 1e3;
        let grey = RGBColor(90, 90, 90);
        chart
            .draw_series([PathElement::new(
                [(0.0, m.kc), (k, m.kc), (k, lo * 0.8)],
                grey.stroke_width(2),
            )])
            .map_err(err)?;
        chart
            .draw_series([Circle::new((k, m.kc), 6, grey.filled())])
            .map_err(err)?;
        chart
            .draw_series([Text::new(
                format!("measured K_c = {:.3} N·m/rad → k2 = {:.1} mm", m.kc, k),
                (k + l2_m * 20.0, m.kc / 1.12),
                ("sans-serif", fs).into_font().color(&grey),
            )])
            .map_err(err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", fs))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;
    Ok(())
}

// ------------------------------------------------------------------------------- signals

/// Grasp signals over time, one entry per sample.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Signals {
    /// Time (s).
    pub t_s: Vec<f64>,
    /// θa (rad).
    pub theta_a_rad: Vec<f64>,
    /// Measured T_a (N·m).
    pub torque_nm: Vec<f64>,
    /// Torque reference (N·m), when recorded.
    pub torque_ref_nm: Option<Vec<f64>>,
    /// Controller state name per sample, when recorded.
    pub state: Option<Vec<String>>,
    /// True contact location (m) per sample, when known (simulation).
    pub k_true_m: Option<Vec<f64>>,
    /// The contact the estimator used: (t, θa,c, T_a,c).
    pub contact: Option<(f64, f64, f64)>,
    /// The estimate: K̂c (N·m/rad), when one was made.
    pub kc_hat: Option<f64>,
}

fn state_color(name: &str) -> RGBColor {
    match name {
        "approach" => RGBColor(222, 235, 247),
        "seating" => RGBColor(239, 237, 245),
        "step" => RGBColor(254, 230, 206),
        "settling" => RGBColor(253, 208, 162),
        "estimating" => RGBColor(229, 245, 224),
        "holding" => RGBColor(199, 233, 192),
        "releasing" | "opening" | "done" => RGBColor(240, 240, 240),
        s if s.starts_with("fault") => RGBColor(252, 187, 161),
        _ => RGBColor(250, 250, 250),
    }
}

/// Draws θa, T_a and the running K̂c over time in three stacked panels (Figs. 5 and 9).
pub fn signals(out: &Path, size: Size, title: &str, s: &Signals) -> Result<(), String> {
    if s.t_s.len() < 2 {
        return Err("nothing to plot: the trace has fewer than two samples".into());
    }
    render(
        out,
        size,
        |r| draw_signals(r, title, s),
        |r| draw_signals(r, title, s),
    )
}

fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x), hi.max(x))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(1e-6);
    (lo - pad, hi + pad)
}

/// State bands: (t0, t1, name) for runs of the same state.
fn bands(s: &Signals) -> Vec<(f64, f64, String)> {
    let Some(states) = &s.state else {
        return vec![];
    };
    let mut out: Vec<(f64, f64, String)> = vec![];
    for (t, st) in s.t_s.iter().zip(states) {
        match out.last_mut() {
            Some(last) if last.2 == *st => last.1 = *t,
            _ => out.push((*t, *t, st.clone())),
        }
    }
    // Close each band at the start of the next.
    for i in 1..out.len() {
        let next = out[i].0;
        out[i - 1].1 = next;
    }
    out
}

/// At most the first, lowest, highest and last point of each of `columns` equal time bins, in
/// time order: what a line `columns` pixels wide can show of a 10 kHz trace, at a fraction of
/// the points (the SVG stays small).
fn envelope(pts: &[(f64, f64)], t0: f64, t1: f64, columns: usize) -> Vec<(f64, f64)> {
    let columns = columns.max(1);
    if pts.len() <= 4 * columns || t1 <= t0 {
        return pts.to_vec();
    }
    let bin = |t: f64| {
        (((t - t0) / (t1 - t0)) * columns as f64).clamp(0.0, columns as f64 - 1.0) as usize
    };
    let mut out = Vec::with_capacity(4 * columns);
    let mut start = 0;
    while start < pts.len() {
        let b = bin(pts[start].0);
        let end = start + pts[start..].iter().take_while(|p| bin(p.0) == b).count();
        let group = &pts[start..end];
        let lo = (0..group.len()).min_by(|&i, &j| group[i].1.total_cmp(&group[j].1));
        let hi = (0..group.len()).max_by(|&i, &j| group[i].1.total_cmp(&group[j].1));
        let mut keep: Vec<usize> = [Some(0), lo, hi, Some(group.len() - 1)]
            .into_iter()
            .flatten()
            .collect();
        keep.sort_unstable();
        keep.dedup();
        out.extend(keep.into_iter().map(|i| group[i]));
        start = end;
    }
    out
}

fn draw_signals<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    s: &Signals,
) -> Result<(), String> {
    let fs = (root.dim_in_pixel().1 / 50).max(12);
    let root = root.titled(title, ("sans-serif", fs + 4)).map_err(err)?;
    let panels = root.split_evenly((3, 1));
    let (t0, t1) = (
        s.t_s.first().copied().unwrap_or(0.0),
        s.t_s.last().copied().unwrap_or(1.0),
    );
    let t1 = if t1 > t0 { t1 } else { t0 + 1.0 };
    let bands = bands(s);
    // Running K̂c after contact: ΔT_a/Δθa from the contact point, where Δθa is meaningful.
    let kc_run: Vec<(f64, f64)> = match s.contact {
        Some((tc, thc, tac)) => s
            .t_s
            .iter()
            .zip(s.theta_a_rad.iter().zip(&s.torque_nm))
            .filter(|(t, _)| **t > tc)
            .filter_map(|(t, (th, ta))| {
                let d = th - thc;
                (d > 2e-3).then(|| (*t, (ta - tac) / d))
            })
            .collect(),
        None => vec![],
    };
    type Series<'a> = Vec<(&'a str, Vec<(f64, f64)>, RGBColor)>;
    let pair =
        |v: &[f64]| -> Vec<(f64, f64)> { s.t_s.iter().copied().zip(v.iter().copied()).collect() };
    let mut torque: Series = vec![("T_a measured", pair(&s.torque_nm), color(1))];
    if let Some(r) = &s.torque_ref_nm {
        torque.push(("T_a reference", pair(r), RGBColor(60, 60, 60)));
    }
    let mut kc: Series = vec![];
    if !kc_run.is_empty() {
        kc.push(("two-point ratio ΔT_a/Δθ_a since contact", kc_run, color(2)));
    }
    let specs: [(&str, Series); 3] = [
        ("θ_a (rad)", vec![("θ_a", pair(&s.theta_a_rad), color(0))]),
        ("T_a (N·m)", torque),
        ("K_c (N·m/rad)", kc),
    ];
    for (i, (panel, (ylabel, series))) in panels.iter().zip(specs).enumerate() {
        let (lo, hi) = if series.is_empty() {
            (0.0, 1.0)
        } else {
            range(series.iter().flat_map(|s| s.1.iter().map(|p| p.1)))
        };
        // The running K̂c is meaningless right after contact (Δθa ≈ 0): show 0 … 3 K̂c.
        let (lo, hi) = match (i, s.kc_hat) {
            (2, Some(k)) if k.is_finite() && k > 0.0 => (0.0, 3.0 * k),
            (2, _) => (lo.max(0.0), hi.min(100.0).max(lo.max(0.0) + 1.0)),
            _ => (lo, hi),
        };
        let columns = panel.dim_in_pixel().0 as usize;
        let series: Series = series
            .into_iter()
            .map(|(l, pts, c)| {
                let pts: Vec<_> = pts
                    .into_iter()
                    .filter(|p| p.1 >= lo && p.1 <= hi && p.0 >= t0 && p.0 <= t1)
                    .collect();
                (l, envelope(&pts, t0, t1, columns), c)
            })
            .collect();
        let mut chart = ChartBuilder::on(panel)
            .margin(fs / 2)
            .x_label_area_size(if i == 2 { fs * 3 } else { fs * 2 })
            .y_label_area_size(fs * 5)
            .build_cartesian_2d(t0..t1, lo..hi)
            .map_err(err)?;
        chart
            .draw_series(
                bands.iter().map(|(a, b, st)| {
                    Rectangle::new([(*a, lo), (*b, hi)], state_color(st).filled())
                }),
            )
            .map_err(err)?;
        let mut mesh = chart.configure_mesh();
        mesh.y_desc(ylabel)
            .label_style(("sans-serif", fs))
            .axis_desc_style(("sans-serif", fs + 1))
            .light_line_style(RGBColor(235, 235, 235).mix(0.5));
        if i == 2 {
            mesh.x_desc("time (s)");
        }
        mesh.draw().map_err(err)?;
        if i == 0 {
            // Label each state band once, at its left edge.
            chart
                .draw_series(
                    bands
                        .iter()
                        .filter(|(a, b, _)| (b - a) / (t1 - t0) > 0.04)
                        .map(|(a, _, st)| {
                            Text::new(
                                st.clone(),
                                (*a + (t1 - t0) * 0.005, hi - (hi - lo) * 0.04),
                                ("sans-serif", fs).into_font().color(&RGBColor(80, 80, 80)),
                            )
                        }),
                )
                .map_err(err)?;
        }
        for (label, pts, col) in series {
            chart
                .draw_series(LineSeries::new(pts, col.stroke_width(2)))
                .map_err(err)?
                .label(label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], col.stroke_width(3)));
        }
        if let Some((tc, thc, tac)) = s.contact.filter(|c| c.0 >= t0 && c.0 <= t1) {
            let y = match i {
                0 => thc,
                1 => tac,
                _ => lo,
            };
            chart
                .draw_series([PathElement::new(
                    [(tc, lo), (tc, hi)],
                    RGBColor(120, 120, 120).stroke_width(1),
                )])
                .map_err(err)?;
            if i < 2 {
                chart
                    .draw_series([Circle::new((tc, y), 5, BLACK.filled())])
                    .map_err(err)?
                    .label("contact used (θ_a,c, T_a,c)")
                    .legend(|(x, y)| Circle::new((x + 10, y), 5, BLACK.filled()));
            }
        }
        if let (2, Some(k)) = (i, s.kc_hat) {
            let col = RGBColor(200, 0, 0);
            chart
                .draw_series([PathElement::new([(t0, k), (t1, k)], col.stroke_width(2))])
                .map_err(err)?
                .label(format!("two-point estimated K_c = {k:.3} N·m/rad"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], col.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            // The state names sit along the top of the first panel; θa rises, so its lower
            // right corner is free.
            .position(if i == 0 {
                SeriesLabelPosition::LowerRight
            } else {
                SeriesLabelPosition::UpperLeft
            })
            .label_font(("sans-serif", fs))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        if i == 2 && s.contact.is_none() {
            chart
                .draw_series([Text::new(
                    "no contact found",
                    (t0 + (t1 - t0) * 0.4, 0.5),
                    ("sans-serif", fs + 2),
                )])
                .map_err(err)?;
        }
    }
    Ok(())
}

// ------------------------------------------------------------------------------- heat map

/// A table of errors over two parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    /// Row parameter name (y axis).
    pub row_name: String,
    /// Column parameter name (x axis).
    pub col_name: String,
    /// Row values.
    pub rows: Vec<f64>,
    /// Column values.
    pub cols: Vec<f64>,
    /// `cells[row][col]`; `None` = no estimate (fault).
    pub cells: Vec<Vec<Option<f64>>>,
    /// What a cell holds (colour bar label).
    pub value_name: String,
    /// Optional note per cell, printed after the value (e.g. "(4/5)"); may be empty.
    pub notes: Vec<Vec<String>>,
    /// Top of the colour scale; `None`: the largest cell.
    pub vmax: Option<f64>,
}

/// Blue (0) → yellow → red (max) colour scale.
fn heat(v: f64, max: f64) -> RGBColor {
    let x = if max > 0.0 {
        (v / max).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let stops = [
        (0.0, (49.0, 54.0, 149.0)),
        (0.25, (116.0, 173.0, 209.0)),
        (0.5, (255.0, 255.0, 191.0)),
        (0.75, (244.0, 109.0, 67.0)),
        (1.0, (165.0, 0.0, 38.0)),
    ];
    let mut prev = stops[0];
    for s in stops {
        if x <= s.0 {
            let f = if s.0 > prev.0 {
                (x - prev.0) / (s.0 - prev.0)
            } else {
                0.0
            };
            let c = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
            return RGBColor(
                c(prev.1 .0, s.1 .0),
                c(prev.1 .1, s.1 .1),
                c(prev.1 .2, s.1 .2),
            );
        }
        prev = s;
    }
    RGBColor(165, 0, 38)
}

/// Draws the table as a heat map with the value printed in each cell.
pub fn heat_map(out: &Path, size: Size, title: &str, t: &Table) -> Result<(), String> {
    if t.rows.is_empty() || t.cols.is_empty() {
        return Err("nothing to plot: the table is empty".into());
    }
    render(
        out,
        size,
        |r| draw_heat(r, title, t),
        |r| draw_heat(r, title, t),
    )
}

fn draw_heat<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    t: &Table,
) -> Result<(), String> {
    let fs = (root.dim_in_pixel().1 / 40).max(12);
    let (w, _) = root.dim_in_pixel();
    let (main, bar) = root.split_horizontally(w.saturating_sub(w / 8 + 40));
    let max = t
        .vmax
        .filter(|v| v.is_finite() && *v > 0.0)
        .unwrap_or_else(|| {
            t.cells
                .iter()
                .flatten()
                .flatten()
                .copied()
                .filter(|v| v.is_finite())
                .fold(0.0f64, f64::max)
        });
    let (nr, nc) = (t.rows.len(), t.cols.len());
    // Cell (r, c) is centred on the integer point (c, r): the mesh's integer key points
    // carry the parameter values.
    let mut chart = ChartBuilder::on(&main)
        .caption(title, ("sans-serif", fs + 6))
        .margin(fs)
        .x_label_area_size(fs * 4)
        .y_label_area_size(fs * 5)
        .build_cartesian_2d(-0.5..nc as f64 - 0.5, -0.5..nr as f64 - 0.5)
        .map_err(err)?;
    let cols = t.cols.clone();
    let rows = t.rows.clone();
    let label = |vals: &[f64], x: f64| -> String {
        let i = x.round();
        if (x - i).abs() < 1e-6 && i >= 0.0 {
            vals.get(i as usize)
                .map(|v| format!("{v}"))
                .unwrap_or_default()
        } else {
            String::new()
        }
    };
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(nc.max(2) * 2 + 1)
        .y_labels(nr.max(2) * 2 + 1)
        .x_label_formatter(&|x| label(&cols, *x))
        .y_label_formatter(&|y| label(&rows, *y))
        .x_desc(t.col_name.as_str())
        .y_desc(t.row_name.as_str())
        .label_style(("sans-serif", fs))
        .axis_desc_style(("sans-serif", fs + 2))
        .draw()
        .map_err(err)?;
    for (r, row) in t.cells.iter().enumerate() {
        for (c, cell) in row.iter().enumerate() {
            let (x, y) = (c as f64 - 0.5, r as f64 - 0.5);
            let fill = match cell {
                Some(v) if v.is_finite() => heat(*v, max),
                _ => RGBColor(200, 200, 200),
            };
            chart
                .draw_series([Rectangle::new([(x, y), (x + 1.0, y + 1.0)], fill.filled())])
                .map_err(err)?;
            chart
                .draw_series([Rectangle::new(
                    [(x, y), (x + 1.0, y + 1.0)],
                    WHITE.stroke_width(1),
                )])
                .map_err(err)?;
            let note = t
                .notes
                .get(r)
                .and_then(|n| n.get(c))
                .filter(|n| !n.is_empty())
                .map(|n| format!(" {n}"))
                .unwrap_or_default();
            let text = match cell {
                Some(v) if v.is_finite() => format!("{v:.1}{note}"),
                _ => format!("none{note}"),
            };
            let dark = matches!(cell, Some(v) if max > 0.0 && (*v / max < 0.2 || *v / max > 0.8));
            let style = ("sans-serif", fs)
                .into_font()
                .color(if dark { &WHITE } else { &BLACK })
                .pos(plotters::style::text_anchor::Pos::new(
                    plotters::style::text_anchor::HPos::Center,
                    plotters::style::text_anchor::VPos::Center,
                ));
            chart
                .draw_series([Text::new(text, (x + 0.5, y + 0.5), style)])
                .map_err(err)?;
        }
    }
    let partial = t.notes.iter().flatten().any(|n| !n.is_empty());
    let missing = t
        .cells
        .iter()
        .flatten()
        .any(|c| !matches!(c, Some(v) if v.is_finite()));
    if partial || missing {
        let mut note =
            String::from("each cell: the worst error over the runs that gave an estimate");
        if partial {
            note.push_str("; (n of m): n of its m runs gave one");
        }
        if missing {
            note.push_str("; grey \"none\": no run did (fault or refused)");
        }
        let (_, h) = main.dim_in_pixel();
        main.draw_text(
            &note,
            &("sans-serif", (fs * 4 / 5).max(10))
                .into_font()
                .color(&RGBColor(70, 70, 70)),
            (fs as i32, h as i32 - fs as i32),
        )
        .map_err(err)?;
    }
    // Colour bar.
    let top = if max > 0.0 { max } else { 1.0 };
    let mut cb = ChartBuilder::on(&bar)
        .margin_top(fs * 3)
        .margin_bottom(fs * 4)
        .margin_right(fs)
        .y_label_area_size(fs * 5)
        .build_cartesian_2d(0.0..1.0, 0.0..top)
        .map_err(err)?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(t.value_name.as_str())
        .label_style(("sans-serif", fs))
        .axis_desc_style(("sans-serif", fs))
        .draw()
        .map_err(err)?;
    let n = 100;
    cb.draw_series((0..n).map(|i| {
        let a = top * i as f64 / n as f64;
        let b = top * (i + 1) as f64 / n as f64;
        Rectangle::new([(0.0, a), (1.0, b)], heat(a, top).filled())
    }))
    .map_err(err)?;
    Ok(())
}

/// K_c(k2) at the free-motion configuration where θ1 = `theta1_c` (the contact instant),
/// `n` points on (0, l2].
pub fn kc_data(model: &pts::Model<f64>, theta1_c: f64, n: usize) -> Result<KcCurve, String> {
    let f = model.finger;
    let ta = f.k1 * (theta1_c - f.theta01);
    let cfg = model
        .free_from_torque(ta)
        .map_err(|e| format!("θ1,c = {theta1_c} rad: {e}"))?;
    let kc_free = model
        .kc_free(cfg.theta2, ta)
        .map_err(|e| format!("θ1,c = {theta1_c} rad: {e}"))?;
    let kc_proximal = model
        .kc_proximal(cfg.theta2, ta)
        .map_err(|e| format!("θ1,c = {theta1_c} rad: {e}"))?;
    let n = n.max(2);
    let points = (1..=n)
        .filter_map(|i| {
            let k2 = f.l2 * i as f64 / n as f64;
            model
                .kc_distal(cfg.theta2, ta, k2)
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .map(|v| (k2, v))
        })
        .collect();
    Ok(KcCurve {
        label: format!(
            "θ1,c = {theta1_c:.4} rad (θ2 = {:.3} rad, T_a,c = {ta:.3} N·m)",
            cfg.theta2
        ),
        points,
        kc_free,
        kc_proximal,
    })
}

#[cfg(test)]
mod envelope_tests {
    use super::envelope;

    #[test]
    fn keeps_each_bins_extremes_in_time_order() {
        // 10 000 samples of a sawtooth into 10 bins: every bin keeps its first, min, max, last.
        let pts: Vec<(f64, f64)> = (0..10_000)
            .map(|i| (i as f64 * 1e-4, ((i % 37) as f64) - 18.0))
            .collect();
        let e = envelope(&pts, 0.0, 1.0, 10);
        assert!(e.len() <= 40, "{}", e.len());
        assert!(e.windows(2).all(|w| w[0].0 <= w[1].0), "time order");
        for b in 0..10 {
            let (a, z) = (b as f64 * 0.1, (b + 1) as f64 * 0.1);
            let inside = |p: &&(f64, f64)| p.0 >= a && p.0 < z;
            let want_max = pts
                .iter()
                .filter(inside)
                .map(|p| p.1)
                .fold(f64::MIN, f64::max);
            let want_min = pts
                .iter()
                .filter(inside)
                .map(|p| p.1)
                .fold(f64::MAX, f64::min);
            let got: Vec<f64> = e.iter().filter(inside).map(|p| p.1).collect();
            assert!(
                got.contains(&want_max) && got.contains(&want_min),
                "bin {b}"
            );
        }
        // Short series pass through unchanged.
        assert_eq!(envelope(&pts[..30], 0.0, 1.0, 10), pts[..30].to_vec());
    }
}
