//! Figures like the paper's: a metric against millions of transitions, the mean over seeds as a line
//! and the min-max band over seeds as a shaded area, as PNG and SVG.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::learn::EvalRecord;

/// Font used for PNG text (Debian package `fonts-dejavu-core`).
pub const FONT_PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// No evaluation records to plot.
    #[error("no evaluation records to plot")]
    Empty,
    /// The PNG font is missing.
    #[error("font {path} not found: install it (Debian: apt-get install fonts-dejavu-core)")]
    Font {
        /// Path tried.
        path: String,
    },
    /// The plotting backend failed.
    #[error("drawing {path}: {message}")]
    Draw {
        /// Output file.
        path: PathBuf,
        /// Backend message.
        message: String,
    },
}

/// What the y axis shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    /// Mean return of the noise-free evaluation episodes.
    MeanReturn,
    /// Success rate of the evaluation episodes.
    SuccessRate,
    /// Mean return of the training episodes (with exploration noise, from the training starts:
    /// under instructive start states this is where learning shows first).
    TrainReturn,
}

/// What the x axis counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum XAxis {
    /// Transitions of all workers together.
    Total,
    /// Transitions of one worker (total divided by the number of workers).
    PerWorker,
    /// Wall-clock time of the run (the records' `wall_s`), in minutes.
    WallClock,
}

impl XAxis {
    /// The axis value of a record, in the axis's unit (millions of transitions, or minutes).
    fn value(self, r: &EvalRecord) -> f64 {
        let workers = r.transitions_per_worker.len().max(1) as f64;
        match self {
            XAxis::Total => r.transitions as f64 / 1e6,
            XAxis::PerWorker => r.transitions as f64 / workers / 1e6,
            XAxis::WallClock => r.wall_s / 60.0,
        }
    }
}

/// One curve: a label and the evaluation records of each seed.
#[derive(Debug, Clone)]
pub struct Condition {
    /// Legend label.
    pub label: String,
    /// Records per seed.
    pub seeds: Vec<Vec<EvalRecord>>,
}

/// A published figure drawn over the curves (dashed, black or grey): a success level (a horizontal line on
/// the success plots), a budget in transitions (a vertical line on the plots against transitions),
/// or both (their crossing, e.g. "95.5% within 1M transitions").
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mark {
    /// Legend label, e.g. "paper: 95.5% (Table II)".
    pub label: String,
    /// Success rate in [0, 1], drawn on the success plots.
    #[serde(default)]
    pub success: Option<f64>,
    /// Transitions (all workers), drawn on the plots against transitions.
    #[serde(default)]
    pub transitions: Option<u64>,
}

impl Mark {
    /// Refuses a mark that draws nothing or lies off its axes.
    pub fn validate(&self) -> Result<(), String> {
        if self.success.is_none() && self.transitions.is_none() {
            return Err(format!(
                "mark `{}` sets neither success nor transitions",
                self.label
            ));
        }
        if let Some(s) = self.success
            && !(0.0..=1.0).contains(&s)
        {
            return Err(format!(
                "mark `{}`: success {s} is not in [0, 1]",
                self.label
            ));
        }
        Ok(())
    }

    /// The vertical line's position on axis `x`, when the mark has one there.
    fn x_on(&self, x: XAxis) -> Option<f64> {
        match x {
            XAxis::Total => self.transitions.map(|t| t as f64 / 1e6),
            XAxis::PerWorker | XAxis::WallClock => None,
        }
    }

    /// The horizontal line's level on a plot of `metric`, when the mark has one there.
    fn y_on(&self, metric: Metric) -> Option<f64> {
        match metric {
            Metric::SuccessRate => self.success,
            Metric::MeanReturn | Metric::TrainReturn => None,
        }
    }
}

/// Mean, min and max over seeds at each evaluation index that every seed reached.
pub fn aggregate(seeds: &[Vec<EvalRecord>], metric: Metric, x: XAxis) -> Vec<(f64, f64, f64, f64)> {
    let n = seeds.iter().map(Vec::len).min().unwrap_or(0);
    (0..n)
        .map(|i| {
            let xs: Vec<f64> = seeds.iter().map(|s| x.value(&s[i])).collect();
            let ys: Vec<f64> = seeds
                .iter()
                .map(|s| match metric {
                    Metric::MeanReturn => s[i].mean_return,
                    Metric::SuccessRate => s[i].success_rate,
                    Metric::TrainReturn => s[i].train_return,
                })
                .collect();
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            let min = ys.iter().copied().fold(f64::INFINITY, f64::min);
            let max = ys.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (mean(&xs), mean(&ys), min, max)
        })
        .collect()
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    conditions: &[Condition],
    marks: &[Mark],
    metric: Metric,
    x: XAxis,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let series: Vec<Vec<(f64, f64, f64, f64)>> = conditions
        .iter()
        .map(|c| aggregate(&c.seeds, metric, x))
        .collect();
    let x_max = series
        .iter()
        .flatten()
        .map(|p| p.0)
        .chain(marks.iter().filter_map(|m| m.x_on(x)))
        .fold(1e-6, f64::max);
    let (y_min, y_max) = series
        .iter()
        .flatten()
        .fold((0.0f64, 0.0f64), |(lo, hi), p| (lo.min(p.2), hi.max(p.3)));
    // Keep a readable range when every value is (nearly) the same.
    let y_max = y_max.max(
        y_min
            + match metric {
                Metric::SuccessRate => 1.0,
                Metric::MeanReturn | Metric::TrainReturn => 0.1,
            },
    );
    let y_label = match metric {
        Metric::MeanReturn => "mean episode return",
        Metric::SuccessRate => "success rate",
        Metric::TrainReturn => "mean training episode return",
    };
    let x_label = match x {
        XAxis::Total => "transitions (millions, all workers)",
        XAxis::PerWorker => "transitions (millions, per worker)",
        XAxis::WallClock => "wall-clock (minutes)",
    };
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..x_max * 1.02, y_min..y_max * 1.05)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| format!("{v:.3}"))
        .y_label_formatter(&|v| format!("{v:.2}"))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, (c, s)) in conditions.iter().zip(&series).enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        if s.len() > 1 {
            let mut band: Vec<(f64, f64)> = s.iter().map(|p| (p.0, p.3)).collect();
            band.extend(s.iter().rev().map(|p| (p.0, p.2)));
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band,
                    colour.mix(0.2).filled(),
                )))
                .map_err(|e| e.to_string())?;
        }
        chart
            .draw_series(LineSeries::new(
                s.iter().map(|p| (p.0, p.1)),
                colour.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label(format!("{} ({} seeds)", c.label, c.seeds.len()))
            .legend(move |(lx, ly)| {
                PathElement::new(vec![(lx, ly), (lx + 18, ly)], colour.stroke_width(2))
            });
    }
    // Marks in black and dark greys, apart from the curves' palette colours.
    const MARK_COLOURS: [RGBColor; 3] = [BLACK, RGBColor(120, 120, 120), RGBColor(40, 40, 140)];
    for (k, m) in marks.iter().enumerate() {
        let colour = MARK_COLOURS[k % MARK_COLOURS.len()];
        let (mx, my) = (m.x_on(x), m.y_on(metric));
        // The crossing of a level and a budget is drawn as a corner: up to the level, then left.
        let points = match (mx, my) {
            (Some(vx), Some(vy)) => vec![(vx, y_min), (vx, vy), (0.0, vy)],
            (Some(vx), None) => vec![(vx, y_min), (vx, y_max * 1.05)],
            (None, Some(vy)) => vec![(0.0, vy), (x_max * 1.02, vy)],
            (None, None) => continue,
        };
        chart
            .draw_series(DashedLineSeries::new(points, 8, 5, colour.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(m.label.clone())
            .legend(move |(lx, ly)| {
                PathElement::new(vec![(lx, ly), (lx + 18, ly)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

fn register_font() -> Result<(), PlotError> {
    let bytes = std::fs::read(FONT_PATH).map_err(|_| PlotError::Font {
        path: FONT_PATH.to_string(),
    })?;
    let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    plotters::style::register_font("sans-serif", FontStyle::Normal, leaked).map_err(|_| {
        PlotError::Font {
            path: FONT_PATH.to_string(),
        }
    })
}

/// Draws `stem.png` and `stem.svg` (1000 x 600) and returns both paths.
pub fn plot(
    stem: &Path,
    title: &str,
    conditions: &[Condition],
    marks: &[Mark],
    metric: Metric,
    x: XAxis,
) -> Result<[PathBuf; 2], PlotError> {
    if conditions.iter().all(|c| c.seeds.iter().all(Vec::is_empty)) {
        return Err(PlotError::Empty);
    }
    static FONT: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| register_font().map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|_| PlotError::Font {
            path: FONT_PATH.to_string(),
        })?;
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    draw(
        BitMapBackend::new(&png, (1000, 600)).into_drawing_area(),
        title,
        conditions,
        marks,
        metric,
        x,
    )
    .map_err(|message| PlotError::Draw {
        path: png.clone(),
        message,
    })?;
    draw(
        SVGBackend::new(&svg, (1000, 600)).into_drawing_area(),
        title,
        conditions,
        marks,
        metric,
        x,
    )
    .map_err(|message| PlotError::Draw {
        path: svg.clone(),
        message,
    })?;
    Ok([png, svg])
}

/// Reads a JSON-lines evaluation log; malformed lines are skipped and counted.
pub fn read_eval_log(path: &Path) -> std::io::Result<(Vec<EvalRecord>, usize)> {
    let text = std::fs::read_to_string(path)?;
    let mut records = Vec::new();
    let mut bad = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        match serde_json::from_str::<EvalRecord>(line) {
            Ok(r) => records.push(r),
            Err(_) => bad += 1,
        }
    }
    Ok((records, bad))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(transitions: u64, workers: usize, wall_s: f64, success_rate: f64) -> EvalRecord {
        EvalRecord {
            eval_index: 1,
            episodes: 1,
            transitions,
            transitions_per_worker: vec![transitions / workers as u64; workers],
            updates: 0,
            wall_s,
            mean_return: 0.0,
            success_rate,
            train_return: 0.0,
            worker: 0,
            proposal_share: None,
        }
    }

    #[test]
    fn the_axes_are_millions_of_transitions_or_minutes_and_seeds_are_averaged() {
        let seeds = vec![
            vec![record(2_000_000, 2, 120.0, 0.5)],
            vec![record(4_000_000, 2, 240.0, 1.0)],
        ];
        let at = |x| aggregate(&seeds, Metric::SuccessRate, x)[0];
        assert_eq!(at(XAxis::Total), (3.0, 0.75, 0.5, 1.0));
        assert_eq!(at(XAxis::PerWorker).0, 1.5);
        assert_eq!(at(XAxis::WallClock).0, 3.0);
    }
}
