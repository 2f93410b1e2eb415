//! The figure description and its validation.

/// An sRGB colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Colour {
    pub r: u8,
    pub g: u8,
    pub b: u8,
}

impl Colour {
    pub const fn rgb(r: u8, g: u8, b: u8) -> Self {
        Self { r, g, b }
    }
    pub const BLACK: Self = Self::rgb(0, 0, 0);
    pub const GREY: Self = Self::rgb(128, 128, 128);
    pub const BLUE: Self = Self::rgb(31, 119, 180);
    pub const ORANGE: Self = Self::rgb(255, 127, 14);
    pub const GREEN: Self = Self::rgb(44, 160, 44);
    pub const RED: Self = Self::rgb(214, 39, 40);
    pub const PURPLE: Self = Self::rgb(148, 103, 189);
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkerShape {
    Circle,
    Square,
    Triangle,
    Cross,
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Small filled markers.
    Markers { shape: MarkerShape, colour: Colour },
    /// A polyline through the points in the given order.
    Line { colour: Colour },
    /// Large filled markers with a black outline, for points to call out.
    HighlightedMarkers { shape: MarkerShape, colour: Colour },
}

/// A named set of points. `labels` is empty or has one entry per point; a `Some` label is written
/// beside its point.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub style: Style,
    pub labels: Vec<Option<String>>,
}

impl Series {
    /// A series without point labels.
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>, style: Style) -> Self {
        Self {
            name: name.into(),
            points,
            style,
            labels: Vec::new(),
        }
    }
}

/// A 2-D plot: series over linear or logarithmic x and linear y, with a title, axis labels and a
/// legend (series in order). Size in pixels (SVG user units).
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub series: Vec<Series>,
    pub width: u32,
    pub height: u32,
}

/// Why a figure cannot be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlotError {
    #[error("the figure has no points")]
    NoData,
    #[error("a {width}×{height} image needs {want} RGBA bytes, got {got}")]
    ImageSize {
        width: usize,
        height: usize,
        want: usize,
        got: usize,
    },

    #[error("series {series:?}, point {index}: coordinates must be finite")]
    NonFinite { series: String, index: usize },
    #[error("series {series:?}, point {index}: x must be positive on a logarithmic axis")]
    NonPositiveLogX { series: String, index: usize },
    #[error("series {series:?} has {labels} labels for {points} points")]
    LabelCount {
        series: String,
        labels: usize,
        points: usize,
    },
    #[error("size {width}×{height} must be within {MIN_SIZE}..={MAX_SIZE} pixels on each side")]
    BadSize { width: u32, height: u32 },
    #[error("embedded font could not be loaded")]
    Font,
    #[error("drawing failed: {0}")]
    Render(String),
    #[error("PNG encoding failed: {0}")]
    Png(String),
    /// A mesh picture's view or layout that cannot be drawn (this crate's words).
    #[error("bad view: {0}")]
    BadView(&'static str),
    /// A mesh picture's vertex or overlay point (`what`) with a NaN or infinite coordinate.
    #[error("mesh {mesh}, {what} {index}: coordinates must be finite")]
    NonFiniteCoordinate {
        mesh: usize,
        what: &'static str,
        index: usize,
    },
    /// A mesh picture's triangle naming a vertex that does not exist.
    #[error(
        "mesh {mesh}, triangle {triangle}: vertex {index} is out of range ({vertices} vertices)"
    )]
    VertexIndex {
        mesh: usize,
        triangle: usize,
        index: u32,
        vertices: usize,
    },
}

/// Smallest and largest side in pixels (the largest bounds the RGBA pixmap to 64 MiB).
pub const MIN_SIZE: u32 = 100;
pub const MAX_SIZE: u32 = 4096;

impl Figure {
    /// Checks sizes, coordinates and label counts; returns the data bounds
    /// `(x_min, x_max, y_min, y_max)`.
    pub(crate) fn validate(&self) -> Result<(f64, f64, f64, f64), PlotError> {
        let ok = |s: u32| (MIN_SIZE..=MAX_SIZE).contains(&s);
        if !ok(self.width) || !ok(self.height) {
            return Err(PlotError::BadSize {
                width: self.width,
                height: self.height,
            });
        }
        let mut bounds = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for s in &self.series {
            if !s.labels.is_empty() && s.labels.len() != s.points.len() {
                return Err(PlotError::LabelCount {
                    series: s.name.clone(),
                    labels: s.labels.len(),
                    points: s.points.len(),
                });
            }
            for (index, &(x, y)) in s.points.iter().enumerate() {
                if !x.is_finite() || !y.is_finite() {
                    return Err(PlotError::NonFinite {
                        series: s.name.clone(),
                        index,
                    });
                }
                if self.log_x && x <= 0.0 {
                    return Err(PlotError::NonPositiveLogX {
                        series: s.name.clone(),
                        index,
                    });
                }
                bounds = (
                    bounds.0.min(x),
                    bounds.1.max(x),
                    bounds.2.min(y),
                    bounds.3.max(y),
                );
            }
        }
        if bounds.0 > bounds.1 {
            return Err(PlotError::NoData);
        }
        Ok(bounds)
    }
}
