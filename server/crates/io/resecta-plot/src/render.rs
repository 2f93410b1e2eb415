//! Drawing a [`Figure`] with plotters into an SVG string, rasterised to PNG by resvg.

use std::ops::Range;
use std::sync::{Arc, OnceLock};

use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::element::ComposedElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use resvg::{tiny_skia, usvg};

use crate::figure::{Colour, Figure, MarkerShape, PlotError, Style};

/// The family every text uses; registered with the embedded DejaVu Sans.
const FAMILY: &str = "sans-serif";

fn register_fonts() -> Result<(), PlotError> {
    static OK: OnceLock<bool> = OnceLock::new();
    let ok = *OK.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && plotters::style::register_font(FAMILY, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Font) }
}

fn render_err(e: impl std::fmt::Display) -> PlotError {
    PlotError::Render(e.to_string())
}

fn rgb(c: Colour) -> RGBColor {
    RGBColor(c.r, c.g, c.b)
}

/// A tick label: at most 3 decimals, trailing zeros dropped, K/M for thousands and millions,
/// scientific notation for magnitudes below 0.01.
pub(crate) fn compact(v: f64) -> String {
    let a = v.abs();
    if a > 0.0 && a < 0.01 {
        return format!("{v:.1e}");
    }
    let (s, suffix) = if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e3 {
        (v / 1e3, "K")
    } else {
        (v, "")
    };
    let mut t = format!("{s:.3}");
    if t.contains('.') {
        t = t.trim_end_matches('0').trim_end_matches('.').to_owned();
    }
    if t == "-0" {
        t = "0".to_owned();
    }
    t + suffix
}

/// `[lo, hi]` widened by 5 % of the span on each side (±1, or ±10 % of the value, when flat).
fn pad_linear(lo: f64, hi: f64) -> Range<f64> {
    let span = hi - lo;
    let pad = if span > 0.0 {
        0.05 * span
    } else if lo != 0.0 {
        0.1 * lo.abs()
    } else {
        1.0
    };
    lo - pad..hi + pad
}

/// `[lo, hi]` (positive) widened by 5 % of the span in log space (a factor 1.5 when flat).
fn pad_log(lo: f64, hi: f64) -> Range<f64> {
    let (l, h) = (lo.log10(), hi.log10());
    let pad = if h > l {
        0.05 * (h - l)
    } else {
        1.5f64.log10()
    };
    10f64.powf(l - pad)..10f64.powf(h + pad)
}

/// Outline of a marker of radius `size` pixels, as offsets from its centre (y down).
fn outline(shape: MarkerShape, size: i32) -> Vec<(i32, i32)> {
    let r = size as f64;
    let at = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
    match shape {
        MarkerShape::Circle => (0..20)
            .map(|i| {
                let t = std::f64::consts::TAU * i as f64 / 20.0;
                at(r * t.cos(), r * t.sin())
            })
            .collect(),
        MarkerShape::Square => {
            let h = 0.85 * r;
            vec![at(-h, -h), at(h, -h), at(h, h), at(-h, h)]
        }
        MarkerShape::Triangle => vec![
            at(0.0, -1.2 * r),
            at(1.05 * r, 0.65 * r),
            at(-1.05 * r, 0.65 * r),
        ],
        MarkerShape::Cross => {
            let (w, l) = (0.35 * r, 1.1 * r);
            vec![
                at(-w, -l),
                at(w, -l),
                at(w, -w),
                at(l, -w),
                at(l, w),
                at(w, w),
                at(w, l),
                at(-w, l),
                at(-w, w),
                at(-l, w),
                at(-l, -w),
                at(-w, -w),
            ]
        }
    }
}

type Marker<C, DB> = ComposedElement<C, DB, Polygon<(i32, i32)>, PathElement<(i32, i32)>>;

/// A filled marker with an outline, centred at `at` in any coordinate type.
fn marker<DB: DrawingBackend, C>(
    at: C,
    shape: MarkerShape,
    size: i32,
    fill: ShapeStyle,
    edge: ShapeStyle,
) -> Marker<C, DB> {
    let pts = outline(shape, size);
    let mut closed = pts.clone();
    closed.push(pts[0]);
    EmptyElement::at(at) + Polygon::new(pts, fill) + PathElement::new(closed, edge)
}

/// Draws `fig` (already validated, with data bounds) onto `root`.
pub(crate) fn draw<DB: DrawingBackend>(
    fig: &Figure,
    bounds: (f64, f64, f64, f64),
    root: &DrawingArea<DB, Shift>,
) -> Result<(), PlotError> {
    register_fonts()?;
    root.fill(&WHITE).map_err(render_err)?;
    let (x0, x1, y0, y1) = bounds;
    let y = pad_linear(y0, y1);
    if fig.log_x {
        chart(fig, root, pad_log(x0, x1).log_scale(), y)?;
    } else {
        chart(fig, root, pad_linear(x0, x1), y)?;
    }
    root.present().map_err(render_err)
}

fn chart<DB, X>(
    fig: &Figure,
    root: &DrawingArea<DB, Shift>,
    x: X,
    y: Range<f64>,
) -> Result<(), PlotError>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
{
    // Text and markers scale with the figure; 800 × 600 is the reference.
    let k = (fig.width as f64 / 800.0)
        .min(fig.height as f64 / 600.0)
        .clamp(0.5, 3.0);
    let px = |v: f64| (v * k).round() as i32;
    let font = |pt: f64| (FAMILY, pt * k);
    let mut chart = ChartBuilder::on(root)
        .caption(&fig.title, font(22.0))
        .margin(px(16.0))
        .x_label_area_size(px(52.0))
        .y_label_area_size(px(70.0))
        .build_cartesian_2d(x, y)
        .map_err(render_err)?;
    let fmt = |v: &f64| compact(*v);
    chart
        .configure_mesh()
        .x_desc(fig.x_label.as_str())
        .y_desc(fig.y_label.as_str())
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .label_style(font(14.0))
        .axis_desc_style(font(16.0))
        .light_line_style(RGBColor(238, 238, 238))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()
        .map_err(render_err)?;

    let small = px(4.0).max(2);
    let big = px(7.0).max(3);
    let mut labels: Vec<((f64, f64), &str, bool)> = Vec::new();
    for s in &fig.series {
        let pts = s.points.iter().copied();
        let anno = match s.style {
            Style::Line { colour } => {
                let st = rgb(colour).stroke_width(px(2.0).max(1) as u32);
                chart
                    .draw_series(LineSeries::new(pts, st))
                    .map_err(render_err)?
                    .label(s.name.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], st));
                None
            }
            Style::Markers { shape, colour } => {
                let (fill, edge) = (rgb(colour).mix(0.75).filled(), rgb(colour).stroke_width(1));
                chart
                    .draw_series(pts.map(|p| marker(p, shape, small, fill, edge)))
                    .map_err(render_err)?
                    .label(s.name.as_str())
                    .legend(move |p| marker(p, shape, small, fill, edge));
                Some(false)
            }
            Style::HighlightedMarkers { shape, colour } => {
                let fill = rgb(colour).filled();
                let edge = BLACK.stroke_width(px(1.5).max(1) as u32);
                chart
                    .draw_series(pts.map(|p| marker(p, shape, big, fill, edge)))
                    .map_err(render_err)?
                    .label(s.name.as_str())
                    .legend(move |p| marker(p, shape, big, fill, edge));
                Some(true)
            }
        };
        for (&p, l) in s.points.iter().zip(&s.labels) {
            if let Some(t) = l {
                labels.push((p, t.as_str(), anno == Some(true)));
            }
        }
    }
    // Point labels over all series, on a translucent white box: right of their point, or left of
    // it in the right 40 % of the plot.
    let off = px(8.0);
    let (xr, _) = chart.plotting_area().get_pixel_range();
    let turn = xr.start + (0.6 * (xr.end - xr.start) as f64) as i32;
    for (p, t, bold) in labels {
        let weight = if bold {
            FontStyle::Bold
        } else {
            FontStyle::Normal
        };
        let style = FontDesc::new(FontFamily::Name(FAMILY), 13.0 * k, weight).color(&BLACK);
        let (w, h) = root.estimate_text_size(t, &style).map_err(render_err)?;
        let (w, h) = (w as i32, h as i32);
        let to_left = chart.backend_coord(&p).0 > turn;
        let x0 = if to_left { -off - w } else { off };
        let y0 = -off / 2 - h;
        let pad = px(2.0);
        let element = EmptyElement::at(p)
            + Rectangle::new(
                [(x0 - pad, y0 - pad), (x0 + w + pad, y0 + h + pad)],
                WHITE.mix(0.75).filled(),
            )
            + Text::new(
                t.to_owned(),
                (x0, y0),
                style.pos(Pos::new(HPos::Left, VPos::Top)),
            );
        chart.plotting_area().draw(&element).map_err(render_err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.9))
        .border_style(RGBColor(160, 160, 160))
        .label_font(font(14.0))
        .margin(px(10.0))
        .draw()
        .map_err(render_err)
}

impl Figure {
    /// The figure as an SVG document.
    pub fn to_svg(&self) -> Result<String, PlotError> {
        let bounds = self.validate()?;
        let mut out = String::new();
        {
            let root =
                SVGBackend::with_string(&mut out, (self.width, self.height)).into_drawing_area();
            draw(self, bounds, &root)?;
        }
        Ok(out)
    }

    /// The figure as a PNG image (8-bit RGBA, `width × height`): the SVG of [`Self::to_svg`]
    /// rasterised by resvg with the embedded DejaVu Sans standing in for `sans-serif`.
    pub fn to_png(&self) -> Result<Vec<u8>, PlotError> {
        svg_to_png(&self.to_svg()?, self.width, self.height)
    }
}

/// An SVG document rasterised by resvg onto a white `width × height` RGBA image, with the
/// embedded DejaVu Sans standing in for `sans-serif`, as PNG bytes.
pub(crate) fn svg_to_png(svg: &str, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    let opt = usvg::Options {
        fontdb: font_database(),
        font_family: DEJAVU.into(),
        ..usvg::Options::default()
    };
    let tree = usvg::Tree::from_str(svg, &opt).map_err(render_err)?;
    let mut pixmap =
        tiny_skia::Pixmap::new(width, height).ok_or(PlotError::BadSize { width, height })?;
    pixmap.fill(tiny_skia::Color::WHITE);
    resvg::render(&tree, tiny_skia::Transform::default(), &mut pixmap.as_mut());
    pixmap
        .encode_png()
        .map_err(|e| PlotError::Png(e.to_string()))
}

/// The family name inside the embedded font files.
const DEJAVU: &str = "DejaVu Sans";

/// Font database holding only the embedded DejaVu Sans (regular and bold), also serving as the
/// generic `sans-serif` family; built once.
fn font_database() -> Arc<usvg::fontdb::Database> {
    static DB: OnceLock<Arc<usvg::fontdb::Database>> = OnceLock::new();
    DB.get_or_init(|| {
        let mut db = usvg::fontdb::Database::new();
        db.load_font_data(dejavu::sans::regular().to_vec());
        db.load_font_data(dejavu::sans::bold().to_vec());
        db.set_sans_serif_family(DEJAVU);
        Arc::new(db)
    })
    .clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_tick_labels() {
        assert_eq!(compact(62_000.0), "62K");
        assert_eq!(compact(1_250_000.0), "1.25M");
        assert_eq!(compact(0.5), "0.5");
        assert_eq!(compact(2.0), "2");
        assert_eq!(compact(-0.0), "0");
        assert_eq!(compact(0.0012), "1.2e-3");
        assert_eq!(compact(999.0), "999");
    }

    #[test]
    fn padding() {
        let r = pad_linear(1.0, 3.0);
        assert!((r.start - 0.9).abs() < 1e-12 && (r.end - 3.1).abs() < 1e-12);
        let r = pad_linear(0.0, 0.0);
        assert_eq!((r.start, r.end), (-1.0, 1.0));
        let r = pad_log(10.0, 1000.0);
        assert!((r.start - 10f64.powf(0.9)).abs() < 1e-9);
        let r = pad_log(5.0, 5.0);
        assert!((r.start * 1.5 - 5.0).abs() < 1e-9 && (r.end - 7.5).abs() < 1e-9);
    }
}
