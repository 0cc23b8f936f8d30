//! The report's figures: line charts drawn with `plotters`, each written
//! as SVG (for GitHub and browsers) and PNG (for anything else) from one
//! description.
//!
//! Text is set in a cut of DejaVu Sans embedded in the binary
//! (`coupler/assets`), so drawing needs no font library on the machine
//! and a figure looks the same on every one.

use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::Shift;
use plotters::prelude::*;

/// The font every text of a figure is set in.
pub const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans-subset.ttf");

/// Figure size in pixels (SVG user units alike).
const SIZE: (u32, u32) = (900, 560);

/// Makes the embedded font the one every figure's text is set in.
pub fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType font checked in with the source:
        // a failure here is a broken build, not a user's error.
        if plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_err() {
            panic!("the embedded font coupler/assets/DejaVuSans-subset.ttf does not parse");
        }
    });
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stroke {
    Solid,
    Dashed,
    /// Markers only (one circle per point), no line.
    Markers,
}

/// One curve of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend entry; empty: not in the legend.
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub color: RGBColor,
    pub stroke: Stroke,
    /// Vertical bars (x, low, high): the spread over repeated runs.
    pub bars: Vec<(f64, f64, f64)>,
}

impl Series {
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor, stroke: Stroke) -> Self {
        Series { label: label.into(), points, color, stroke, bars: Vec::new() }
    }
}

/// A line chart: title, axes, curves.
#[derive(Debug, Clone)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Both axes logarithmic (points not above zero are left out).
    pub log_axes: bool,
}

/// The colours of the report: one per aspect ratio or method, readable
/// by the colour-blind (Wong 2011, Nature Methods 8:441).
pub const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
];

impl Chart {
    /// The axes' ranges: every finite point and bar, padded by 5 %.
    fn ranges(&self) -> (Range<f64>, Range<f64>) {
        let mut x = (f64::INFINITY, f64::NEG_INFINITY);
        let mut y = (f64::INFINITY, f64::NEG_INFINITY);
        let mut take = |px: f64, py: f64| {
            if self.drawable(px, py) {
                x = (x.0.min(px), x.1.max(px));
                y = (y.0.min(py), y.1.max(py));
            }
        };
        for s in &self.series {
            s.points.iter().for_each(|&(px, py)| take(px, py));
            s.bars.iter().for_each(|&(px, lo, hi)| {
                take(px, lo);
                take(px, hi)
            });
        }
        let log = self.log_axes;
        let pad = |(lo, hi): (f64, f64)| {
            if !lo.is_finite() {
                return if log { 0.1..1.0 } else { 0.0..1.0 };
            }
            if log {
                // Whole decades, so that the axes carry labels.
                return 10f64.powf(lo.log10().floor())..10f64.powf((hi * 1.0001).log10().ceil());
            }
            let span = if hi > lo { hi - lo } else { lo.abs().max(1.0) };
            (lo - 0.05 * span)..(hi + 0.05 * span)
        };
        (pad(x), pad(y))
    }

    /// Writes `stem.svg` and `stem.png`.
    pub fn write(&self, stem: &Path) -> Result<(), String> {
        register_font();
        // Appended, not `with_extension`: a stem may hold dots.
        let with = |ext: &str| {
            let mut name = stem.as_os_str().to_owned();
            name.push(ext);
            std::path::PathBuf::from(name)
        };
        let (svg, png) = (with(".svg"), with(".png"));
        self.render(SVGBackend::new(&svg, SIZE).into_drawing_area())
            .map_err(|e| format!("cannot draw {}: {e}", svg.display()))?;
        self.render(BitMapBackend::new(&png, SIZE).into_drawing_area())
            .map_err(|e| format!("cannot draw {}: {e}", png.display()))
    }

    fn render<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        root.fill(&WHITE).map_err(err)?;
        let (xr, yr) = self.ranges();
        let mut builder = ChartBuilder::on(&root);
        builder.caption(&self.title, (FONT, 22)).margin(14).x_label_area_size(48).y_label_area_size(64);
        let corner = if self.log_axes {
            let mut chart = builder.build_cartesian_2d(xr.log_scale(), yr.log_scale()).map_err(err)?;
            self.plot(&mut chart).map_err(err)?;
            chart.plotting_area().get_pixel_range()
        } else {
            let mut chart = builder.build_cartesian_2d(xr, yr).map_err(err)?;
            self.plot(&mut chart).map_err(err)?;
            chart.plotting_area().get_pixel_range()
        };
        self.draw_legend(&root, (corner.0.end, corner.1.end)).map_err(err)?;
        root.present().map_err(err)
    }

    /// The mesh, the axes' names and every series, on linear or log axes.
    fn plot<DB: DrawingBackend, X, Y>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
    where
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
        Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        chart
            .configure_mesh()
            .x_desc(&self.x_label)
            .y_desc(&self.y_label)
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 17))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(210, 210, 210))
            .draw()?;
        for s in &self.series {
            let color = s.color;
            let style = color.stroke_width(2);
            let finite: Vec<(f64, f64)> = s.points.iter().copied().filter(|&(x, y)| self.drawable(x, y)).collect();
            match s.stroke {
                Stroke::Solid => chart.draw_series(LineSeries::new(finite, style))?,
                Stroke::Dashed => chart.draw_series(DashedLineSeries::new(finite, 8, 5, style))?,
                Stroke::Markers => chart.draw_series(finite.into_iter().map(|p| Circle::new(p, 4, color.filled())))?,
            };
            let bars = s.bars.iter().filter(|&&(x, lo, hi)| self.drawable(x, lo) && self.drawable(x, hi));
            chart.draw_series(
                bars.map(|&(x, lo, hi)| PathElement::new(vec![(x, lo), (x, hi)], color.stroke_width(2))),
            )?;
        }
        Ok(())
    }

    /// Finite, and positive on log axes.
    fn drawable(&self, x: f64, y: f64) -> bool {
        x.is_finite() && y.is_finite() && (!self.log_axes || (x > 0.0 && y > 0.0))
    }
}

impl Chart {
    /// The legend in the plot's lower right corner (`corner`, pixels):
    /// each labelled series' key drawn as the series is, then its label.
    /// Drawn by hand on the figure: plotters' own legend ties its keys'
    /// lifetime to the backend's.
    fn draw_legend<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        corner: (i32, i32),
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let font: TextStyle = (FONT, 14).into_font().into();
        let entries: Vec<&Series> = self.series.iter().filter(|s| !s.label.is_empty()).collect();
        if entries.is_empty() {
            return Ok(());
        }
        let mut width = 0;
        for s in &entries {
            width = width.max(root.estimate_text_size(&s.label, &font)?.0 as i32);
        }
        let (row, key, pad) = (20, 22, 8);
        let (w, h) = (pad + key + 6 + width + pad, pad + row * entries.len() as i32 + pad / 2);
        let (x0, y0) = (corner.0 - 10 - w, corner.1 - 10 - h);
        root.draw(&Rectangle::new([(x0, y0), (x0 + w, y0 + h)], WHITE.mix(0.85).filled()))?;
        root.draw(&Rectangle::new([(x0, y0), (x0 + w, y0 + h)], RGBColor(160, 160, 160)))?;
        for (i, s) in entries.iter().enumerate() {
            let y = y0 + pad + row * i as i32 + row / 2 - 2;
            let x = x0 + pad;
            let style = s.color.stroke_width(2);
            match s.stroke {
                Stroke::Markers => root.draw(&Circle::new((x + key / 2, y), 4, s.color.filled()))?,
                Stroke::Dashed => {
                    root.draw(&PathElement::new(vec![(x, y), (x + 8, y)], style))?;
                    root.draw(&PathElement::new(vec![(x + 14, y), (x + key, y)], style))?;
                }
                Stroke::Solid => root.draw(&PathElement::new(vec![(x, y), (x + key, y)], style))?,
            }
            root.draw(&Text::new(s.label.clone(), (x + key + 6, y - 8), font.clone()))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chart lands as an SVG holding its text and one polyline per
    /// solid curve, and as a PNG of the figure's size.
    #[test]
    fn a_chart_is_written_as_svg_and_png() {
        let dir = std::env::temp_dir().join(format!("sgf-figure-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let chart = Chart {
            title: "Front, a = 1.5 (τ test)".into(),
            x_label: "t / t_ref".into(),
            y_label: "(X_f − L0) / L0".into(),
            series: vec![
                Series::new("DEM", vec![(0.0, 0.0), (1.0, 1.0), (2.0, 1.5)], PALETTE[0], Stroke::Solid),
                Series::new("MPM", vec![(0.0, 0.0), (1.0, 0.8), (f64::NAN, 2.0)], PALETTE[1], Stroke::Dashed),
                Series {
                    bars: vec![(1.0, 0.9, 1.1)],
                    ..Series::new("", vec![(1.0, 1.0)], PALETTE[2], Stroke::Markers)
                },
            ],
            log_axes: false,
        };
        chart.write(&dir.join("front")).unwrap();
        let svg = std::fs::read_to_string(dir.join("front.svg")).unwrap();
        assert!(svg.contains("Front, a = 1.5 (τ test)") && svg.contains("t / t_ref"), "title and axis in the SVG");
        assert!(svg.contains("DEM") && svg.contains("MPM"), "legend in the SVG");
        assert!(svg.matches("<polyline").count() >= 1, "a line in the SVG");
        let png = std::fs::read(dir.join("front.png")).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        // Width and height: the IHDR chunk's first two big-endian words.
        let w = u32::from_be_bytes(png[16..20].try_into().unwrap());
        let h = u32::from_be_bytes(png[20..24].try_into().unwrap());
        assert_eq!((w, h), SIZE);
        std::fs::remove_dir_all(&dir).ok();
    }
}
