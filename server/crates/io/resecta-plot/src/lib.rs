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
//!
//! [`mesh_svg`]/[`mesh_png`] picture a triangle mesh (a reconstruction, with its samples as
//! dots) flat-shaded in an orthographic view, and [`mesh_panel_svg`]/[`mesh_panel_png`] several
//! side by side at one scale; see [`MeshView`].

mod figure;
mod mesh_view;
mod pareto;
mod raster;
mod render;

pub use figure::{Colour, Figure, MarkerShape, PlotError, Series, Style};
pub use mesh_view::{MeshPanel, MeshView, mesh_panel_png, mesh_panel_svg, mesh_png, mesh_svg};
pub use pareto::pareto_figure;
pub use raster::rgba_png;
