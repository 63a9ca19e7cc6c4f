//! The report's plots, drawn with plotters into RGB images: every plot has
//! a title, axis names with units and a legend, in an embedded font
//! (`assets/fonts/DejaVuSans-subset.ttf`: no system fonts are read, so a
//! plot looks the same on every machine).

use std::path::Path;
use std::sync::Once;

use anyhow::{anyhow, Context, Result};
use image::RgbImage;
use nalgebra::Point3;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

/// The plots' font, registered under plotters' "sans-serif" family.
static FONT_BYTES: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans-subset.ttf");
const FONT: &str = "sans-serif";

/// The estimate (and the worse of two).
pub const RED: RGBColor = RGBColor(215, 40, 40);
/// The ground truth.
pub const BLUE: RGBColor = RGBColor(40, 90, 215);
/// A second estimate (loop corrected, propagator).
pub const GREEN: RGBColor = RGBColor(30, 160, 70);
/// Reference lines and context.
pub const GREY: RGBColor = RGBColor(120, 120, 120);

const TITLE_PX: u32 = 22;
const LABEL_PX: u32 = 15;

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is part of the binary; a failure here is a build defect.
        if plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_err() {
            panic!("the embedded plot font is not a valid TrueType font");
        }
    });
}

fn plot_err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("plotting: {e}")
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type Chart2d<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws into a fresh white `width` x `height` image.
fn draw(width: u32, height: u32, paint: impl FnOnce(&Area<'_>) -> Result<()>) -> Result<RgbImage> {
    let mut img = RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    draw_on(&mut img, paint)?;
    Ok(img)
}

/// Draws over an existing image.
fn draw_on(img: &mut RgbImage, paint: impl FnOnce(&Area<'_>) -> Result<()>) -> Result<()> {
    register_font();
    let size = img.dimensions();
    let root = BitMapBackend::with_buffer(img.as_mut(), size).into_drawing_area();
    paint(&root)?;
    root.present().map_err(plot_err)
}

/// The series legend inside a chart, in a box at `position`.
fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart2d<'a, 'b>,
    position: SeriesLabelPosition,
    font_px: u32,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .label_font((FONT, font_px))
        .background_style(WHITE.mix(0.85))
        .border_style(GREY)
        .draw()
        .map_err(plot_err)
}

/// Writes a plot as PNG, naming the file when it cannot.
pub fn save(img: &RgbImage, path: &Path) -> Result<()> {
    img.save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// The two views of a trajectory plot: the plane of the ground truth's two
/// largest extents, and the largest against the smallest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Views {
    /// The two largest extents (axis indices, horizontal then vertical).
    pub first: (usize, usize),
    /// The largest against the smallest.
    pub second: (usize, usize),
}

/// Axis index to name.
pub const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

impl Views {
    /// From the ground truth's extent per axis.
    pub fn of(ground_truth: &[Point3<f64>]) -> Self {
        let extent = |k: usize| {
            let (lo, hi) = ground_truth
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p[k]), hi.max(p[k]))
                });
            hi - lo
        };
        let mut axes = [0usize, 1, 2];
        axes.sort_by(|a, b| extent(*b).total_cmp(&extent(*a)));
        Self {
            first: (axes[0], axes[1]),
            second: (axes[0], axes[2]),
        }
    }

    /// The views in words, for the report.
    pub fn describe(&self) -> String {
        let n = |(a, b): (usize, usize)| format!("{}-{}", AXIS_NAMES[a], AXIS_NAMES[b]);
        format!(
            "{} (the ground truth's two largest extents) and {}",
            n(self.first),
            n(self.second)
        )
    }
}

/// Ground truth and aligned estimate in two views with the same scale on
/// both axes; the estimate coloured by its position error (colour bar
/// right), the start marked, and a ring on the estimate at each index in
/// `loops` (where a loop closed).
pub fn trajectory(
    pairs: &[(Point3<f64>, Point3<f64>)],
    loops: &[usize],
    title: &str,
) -> Result<(RgbImage, Views)> {
    anyhow::ensure!(!pairs.is_empty(), "no poses to plot");
    let gt: Vec<Point3<f64>> = pairs.iter().map(|(g, _)| *g).collect();
    let views = Views::of(&gt);
    let errors: Vec<f64> = pairs.iter().map(|(g, e)| (g - e).norm()).collect();
    let max_err = errors.iter().cloned().fold(0.0, f64::max).max(1e-6);
    let (w, h) = (1100u32, 520u32);
    let img = draw(w, h, |root| {
        let root = root.titled(title, (FONT, TITLE_PX)).map_err(plot_err)?;
        let (plots, bar) = root.split_horizontally(w - 110);
        let panels = plots.split_evenly((1, 2));
        for (panel, (a, b)) in panels.iter().zip([views.first, views.second]) {
            let (ax, ay) = (AXIS_NAMES[a], AXIS_NAMES[b]);
            // Equal scale: one span for both axes, centred on the data.
            let pts = pairs.iter().flat_map(|(g, e)| [(g[a], g[b]), (e[a], e[b])]);
            let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for (x, y) in pts {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
            let span = (x1 - x0).max(y1 - y0).max(1e-3) * 1.1;
            let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{ax}-{ay} view"), (FONT, LABEL_PX + 2))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(
                    cx - span / 2.0..cx + span / 2.0,
                    cy - span / 2.0..cy + span / 2.0,
                )
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc(format!("{ax} (m)"))
                .y_desc(format!("{ay} (m)"))
                .label_style((FONT, LABEL_PX - 2))
                .axis_desc_style((FONT, LABEL_PX))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(plot_err)?;
            chart
                .draw_series(LineSeries::new(
                    pairs.iter().map(|(g, _)| (g[a], g[b])),
                    GREY.stroke_width(2),
                ))
                .map_err(plot_err)?
                .label("ground truth")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GREY.stroke_width(2)));
            chart
                .draw_series(pairs.windows(2).zip(&errors).map(|(w, err)| {
                    let c = ViridisRGB.get_color_normalized(*err, 0.0, max_err);
                    PathElement::new(
                        vec![(w[0].1[a], w[0].1[b]), (w[1].1[a], w[1].1[b])],
                        c.stroke_width(2),
                    )
                }))
                .map_err(plot_err)?
                .label("estimate (aligned), colour: ATE")
                .legend(|(x, y)| {
                    PathElement::new(
                        vec![(x, y), (x + 20, y)],
                        ViridisRGB.get_color(0.5).stroke_width(2),
                    )
                });
            let start = pairs[0].0;
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [
                        (start[a] - span * 0.01, start[b] - span * 0.01),
                        (start[a] + span * 0.01, start[b] + span * 0.01),
                    ],
                    RED.filled(),
                )))
                .map_err(plot_err)?
                .label("start")
                .legend(|(x, y)| Rectangle::new([(x + 6, y - 4), (x + 14, y + 4)], RED.filled()));
            let marks: Vec<(f64, f64)> = loops
                .iter()
                .filter_map(|&i| pairs.get(i))
                .map(|(_, e)| (e[a], e[b]))
                .collect();
            if !marks.is_empty() {
                chart
                    .draw_series(
                        marks
                            .iter()
                            .map(|&p| Circle::new(p, 7, MAGENTA.stroke_width(3))),
                    )
                    .map_err(plot_err)?
                    .label("loop closed")
                    .legend(|(x, y)| Circle::new((x + 10, y), 5, MAGENTA.stroke_width(2)));
            }
            draw_legend(&mut chart, SeriesLabelPosition::UpperLeft, LABEL_PX - 2)?;
        }
        colour_bar(&bar, max_err)
    })?;
    Ok((img, views))
}

/// A vertical viridis bar from 0 to `max` metres.
fn colour_bar(area: &Area<'_>, max: f64) -> Result<()> {
    let mut chart = ChartBuilder::on(area)
        .caption("ATE (m)", (FONT, LABEL_PX))
        .margin_top(50)
        .margin_bottom(52)
        .margin_right(10)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..1.0, 0.0..max)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .disable_y_mesh()
        .disable_x_axis()
        .label_style((FONT, LABEL_PX - 3))
        .y_label_formatter(&|v| format!("{v:.3}"))
        .draw()
        .map_err(plot_err)?;
    let steps = 100;
    chart
        .draw_series((0..steps).map(|i| {
            let (lo, hi) = (
                max * i as f64 / steps as f64,
                max * (i + 1) as f64 / steps as f64,
            );
            Rectangle::new(
                [(0.0, lo), (1.0, hi)],
                ViridisRGB
                    .get_color_normalized((lo + hi) / 2.0, 0.0, max)
                    .filled(),
            )
        }))
        .map_err(plot_err)?;
    Ok(())
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Points joined in order.
    Line,
    /// Points alone.
    Dots,
}

/// One series of an x-y chart, with its legend name.
pub struct Series<'a> {
    /// Legend name.
    pub name: &'a str,
    /// (x, y) in data units.
    pub points: Vec<(f64, f64)>,
    /// Its colour.
    pub colour: RGBColor,
    /// Line or dots.
    pub style: Style,
}

/// A horizontal reference line (RMSE, median), with its legend name.
pub struct Level {
    /// Legend name.
    pub name: String,
    /// Its y value.
    pub value: f64,
    /// Its colour.
    pub colour: RGBColor,
}

/// What an x-y chart shows.
pub struct Chart<'a> {
    /// Above the chart.
    pub title: &'a str,
    /// The x axis label.
    pub x_desc: &'a str,
    /// The y axis label.
    pub y_desc: &'a str,
    /// The data.
    pub series: Vec<Series<'a>>,
    /// Reference lines.
    pub levels: Vec<Level>,
    /// Fixed y range top (IoU: 1.0); None: from the data.
    pub y_max: Option<f64>,
}

/// Lines and dots against x, with reference levels and a legend.
pub fn chart(spec: &Chart<'_>, width: u32, height: u32) -> Result<RgbImage> {
    let all = spec.series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y1) = (f64::MAX, f64::MIN, 0.0f64);
    for (x, y) in all {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y1 = y1.max(*y);
    }
    for l in &spec.levels {
        y1 = y1.max(l.value);
    }
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    let y1 = spec.y_max.unwrap_or((y1 * 1.1).max(1e-6));
    draw(width, height, |root| {
        // The legend beside the plot, where it never hides a point.
        let (plot_area, legend_area) = root.split_horizontally(width - 190);
        let mut entries: Vec<(String, RGBColor, Style)> = spec
            .series
            .iter()
            .map(|s| (s.name.to_string(), s.colour, s.style))
            .collect();
        entries.extend(
            spec.levels
                .iter()
                .map(|l| (l.name.clone(), l.colour, Style::Line)),
        );
        side_legend(&legend_area, &entries)?;
        let mut chart = ChartBuilder::on(&plot_area)
            .caption(spec.title, (FONT, TITLE_PX))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(62)
            .build_cartesian_2d(x0..x1, 0.0..y1)
            .map_err(plot_err)?;
        let x_decimals = decimals_for(x1 - x0);
        chart
            .configure_mesh()
            .x_desc(spec.x_desc)
            .y_desc(spec.y_desc)
            .x_label_formatter(&|v| format!("{v:.x_decimals$}"))
            .label_style((FONT, LABEL_PX - 2))
            .axis_desc_style((FONT, LABEL_PX))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(plot_err)?;
        for s in &spec.series {
            let colour = s.colour;
            match s.style {
                Style::Line => chart
                    .draw_series(LineSeries::new(
                        s.points.iter().copied(),
                        colour.stroke_width(2),
                    ))
                    .map_err(plot_err)?,
                Style::Dots => chart
                    .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(plot_err)?,
            };
        }
        for l in &spec.levels {
            chart
                .draw_series(LineSeries::new(
                    [(x0, l.value), (x1, l.value)],
                    l.colour.stroke_width(1),
                ))
                .map_err(plot_err)?;
        }
        Ok(())
    })
}

/// A legend drawn in its own area: a marker and a name per entry.
fn side_legend(area: &Area<'_>, entries: &[(String, RGBColor, Style)]) -> Result<()> {
    let text = (FONT, LABEL_PX - 1).into_text_style(area);
    let mut y = 50i32;
    for (name, colour, style) in entries {
        match style {
            Style::Line => area.draw(&PathElement::new(
                vec![(6, y + 8), (28, y + 8)],
                colour.stroke_width(2),
            )),
            Style::Dots => area.draw(&Circle::new((17, y + 8), 4, colour.filled())),
        }
        .map_err(plot_err)?;
        area.draw_text(name, &text, (36, y)).map_err(plot_err)?;
        y += 24;
    }
    Ok(())
}

/// Decimals that tell tick labels apart over a span (frames: none).
fn decimals_for(span: f64) -> usize {
    if span >= 20.0 {
        0
    } else if span >= 2.0 {
        1
    } else {
        2
    }
}

/// One latency histogram: a stage's per-frame times.
pub struct Histogram<'a> {
    /// The stage's name.
    pub stage: &'a str,
    /// Its time on each frame, milliseconds.
    pub values_ms: Vec<f64>,
    /// Median, drawn as a line.
    pub p50_ms: f64,
    /// 99th percentile, drawn as a line.
    pub p99_ms: f64,
}

/// One histogram panel per stage, stacked, each titled with its stage and
/// with p50 / p99 marked.
pub fn histograms(panels: &[Histogram<'_>], title: &str) -> Result<RgbImage> {
    anyhow::ensure!(!panels.is_empty(), "no latency to plot");
    let (w, panel_h) = (900u32, 200u32);
    let h = 40 + panel_h * panels.len() as u32;
    draw(w, h, |root| {
        let root = root.titled(title, (FONT, TITLE_PX)).map_err(plot_err)?;
        let areas = root.split_evenly((panels.len(), 1));
        for (area, p) in areas.iter().zip(panels) {
            let x_max = (p.p99_ms * 1.25).max(1.0);
            let bins = 60usize;
            let width = x_max / bins as f64;
            let mut counts = vec![0u32; bins];
            for v in &p.values_ms {
                counts[((v / width) as usize).min(bins - 1)] += 1;
            }
            let y_max = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.15;
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!("{} ({} frames)", p.stage, p.values_ms.len()),
                    (FONT, LABEL_PX + 1),
                )
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(56)
                .build_cartesian_2d(0.0..x_max, 0.0..y_max)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("ms per frame (last bin: this and slower)")
                .y_desc("frames")
                .x_label_formatter(&|v| format!("{v:.0}"))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .label_style((FONT, LABEL_PX - 3))
                .axis_desc_style((FONT, LABEL_PX - 2))
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(plot_err)?;
            chart
                .draw_series(counts.iter().enumerate().map(|(i, &c)| {
                    Rectangle::new(
                        [(i as f64 * width, 0.0), ((i + 1) as f64 * width, c as f64)],
                        BLUE.mix(0.75).filled(),
                    )
                }))
                .map_err(plot_err)?
                .label("frames per bin")
                .legend(|(x, y)| Rectangle::new([(x + 4, y - 4), (x + 14, y + 4)], BLUE.filled()));
            for (name, v, colour) in [("p50", p.p50_ms, GREEN), ("p99", p.p99_ms, RED)] {
                chart
                    .draw_series(LineSeries::new(
                        [(v, 0.0), (v, y_max)],
                        colour.stroke_width(2),
                    ))
                    .map_err(plot_err)?
                    .label(format!("{name} {v:.1} ms"))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                    });
            }
            draw_legend(&mut chart, SeriesLabelPosition::UpperRight, LABEL_PX - 3)?;
        }
        Ok(())
    })
}

/// A picture (the mask strip) under a title bar with a legend of colours;
/// `labels` are drawn at pixel positions of the picture.
pub fn titled_picture(
    picture: &RgbImage,
    title: &str,
    legend: &[(&str, RGBColor)],
    labels: &[(String, (i32, i32))],
) -> Result<RgbImage> {
    let bar = 64u32;
    let mut img = RgbImage::from_pixel(
        picture.width(),
        picture.height() + bar,
        image::Rgb([255, 255, 255]),
    );
    image::imageops::replace(&mut img, picture, 0, bar as i64);
    draw_on(&mut img, |root| {
        root.draw_text(title, &(FONT, TITLE_PX).into_text_style(root), (10, 6))
            .map_err(plot_err)?;
        let mut x = 10i32;
        for (name, colour) in legend {
            root.draw(&Rectangle::new([(x, 40), (x + 16, 54)], colour.filled()))
                .map_err(plot_err)?;
            root.draw_text(name, &(FONT, LABEL_PX).into_text_style(root), (x + 22, 39))
                .map_err(plot_err)?;
            x += 30 + 9 * name.len() as i32;
        }
        let style = (FONT, TITLE_PX).into_font().color(&YELLOW);
        for (text, (x, y)) in labels {
            let (tw, th) = root.estimate_text_size(text, &style).map_err(plot_err)?;
            let (x, y) = (*x, *y + bar as i32);
            root.draw(&Rectangle::new(
                [(x - 4, y - 2), (x + tw as i32 + 4, y + th as i32 + 2)],
                BLACK.mix(0.6).filled(),
            ))
            .map_err(plot_err)?;
            root.draw_text(text, &style, (x, y)).map_err(plot_err)?;
        }
        Ok(())
    })?;
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ink(img: &RgbImage) -> usize {
        img.pixels().filter(|p| p.0 != [255, 255, 255]).count()
    }

    #[test]
    fn views_follow_the_ground_truths_extent() {
        // Mostly along z, then x, hardly y (a camera carried at one height).
        let gt: Vec<Point3<f64>> = (0..20)
            .map(|i| Point3::new(0.1 * i as f64, 0.001 * i as f64, 0.3 * i as f64))
            .collect();
        let v = Views::of(&gt);
        assert_eq!(v.first, (2, 0));
        assert_eq!(v.second, (2, 1));
        assert!(v.describe().starts_with("z-x"), "{}", v.describe());
    }

    #[test]
    fn plots_have_their_size_and_text() {
        let pairs: Vec<_> = (0..50)
            .map(|i| {
                let a = i as f64 * 0.1;
                (
                    Point3::new(a.cos(), a.sin(), 0.1 * a),
                    Point3::new(a.cos() + 0.01 * a, a.sin(), 0.1 * a),
                )
            })
            .collect();
        let (img, _) = trajectory(&pairs, &[3], "trajectory").unwrap();
        assert_eq!(img.dimensions(), (1100, 520));
        // The loop mark is drawn (in both views), and only where asked.
        let magenta = |img: &RgbImage| img.pixels().filter(|p| p.0 == [255, 0, 255]).count();
        let (plain, _) = trajectory(&pairs, &[], "trajectory").unwrap();
        assert!(magenta(&img) > 100 + magenta(&plain), "{}", magenta(&img));
        assert!(ink(&img) > 10_000);
        let c = chart(
            &Chart {
                title: "ATE over time",
                x_desc: "time (s)",
                y_desc: "error (m)",
                series: vec![Series {
                    name: "ATE",
                    points: (0..30).map(|i| (i as f64, 0.01 * i as f64)).collect(),
                    colour: RED,
                    style: Style::Line,
                }],
                levels: vec![Level {
                    name: "RMSE".into(),
                    value: 0.1,
                    colour: GREY,
                }],
                y_max: None,
            },
            900,
            320,
        )
        .unwrap();
        assert_eq!(c.dimensions(), (900, 320));
        // Title text is drawn: dark pixels in the caption band.
        let dark_in_title = (0..900)
            .flat_map(|x| (0..28).map(move |y| (x, y)))
            .filter(|&(x, y)| c.get_pixel(x, y).0.iter().all(|&v| v < 100))
            .count();
        assert!(dark_in_title > 100, "{dark_in_title}");
        let h = histograms(
            &[Histogram {
                stage: "track",
                values_ms: vec![1.0, 2.0, 2.5, 3.0],
                p50_ms: 2.2,
                p99_ms: 3.0,
            }],
            "latency",
        )
        .unwrap();
        assert_eq!(h.dimensions(), (900, 240));
    }
}
