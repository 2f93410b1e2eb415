//! Scatter and line plots for study and benchmark figures, rendered in memory: SVG as text
//! ([`Figure::to_svg`]) and PNG as bytes ([`Figure::to_png`]); nothing is written to disk.
//!
//! Pure Rust, no system libraries: `plotters` draws the SVG (its text layout measures glyphs with
//! `ab_glyph` from a DejaVu Sans embedded by the `dejavu` crate; the SVG's text names the
//! `sans-serif` family and is laid out by the viewer); `resvg` rasterises that SVG to PNG with the
//! same embedded font, so both outputs show the same figure.
//!
//! [`pareto_figure`] draws the accuracy–complexity figure of Paper I (thesis Fig. 6.7) from a
//! [`resecta_meshmetrics::Study`].

mod figure;
mod pareto;
mod raster;
mod render;

pub use figure::{Colour, Figure, MarkerShape, PlotError, Series, Style};
pub use pareto::pareto_figure;
pub use raster::rgba_png;
