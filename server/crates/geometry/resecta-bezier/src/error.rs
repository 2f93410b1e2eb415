//! Typed errors of the Bézier layer.

/// What can be wrong with a control net, a resolution or an output buffer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BezierError {
    #[error("{axis} direction needs at least 2 control points, got {got}")]
    TooFewControlPoints { axis: char, got: usize },
    #[error("{axis} direction has {got} control points; the cap is {max}")]
    TooManyControlPoints { axis: char, got: usize, max: usize },
    #[error("control net of {m}x{n} needs {expected} points, got {got}")]
    PointCount {
        m: usize,
        n: usize,
        expected: usize,
        got: usize,
    },
    #[error("control point {index} is not finite")]
    NonFinite { index: usize },
    #[error("control point ({i}, {j}) is outside the {m}x{n} net")]
    IndexOutOfRange {
        i: usize,
        j: usize,
        m: usize,
        n: usize,
    },
    #[error("{axis} resolution must be at least 2, got {got}")]
    ResolutionTooSmall { axis: char, got: usize },
    #[error("{axis} resolution {got} exceeds the cap {max}")]
    ResolutionTooLarge { axis: char, got: usize, max: usize },
    #[error("resolution {ru}x{rv} exceeds the cap of {max} samples")]
    TooManySamples { ru: usize, rv: usize, max: usize },
    #[error("output buffer holds {got} values, {expected} needed")]
    BufferLength { expected: usize, got: usize },
    #[error("surface grid lacks {0}")]
    MissingOutput(&'static str),
    #[error("mesh: {0}")]
    Mesh(#[from] resecta_geom::GeomError),
    /// The device an evaluator runs on failed (e.g. a lost GPU); the CPU evaluator can take over.
    #[error("evaluation device failed: {0}")]
    Device(String),
}

impl BezierError {
    /// Whether the evaluating device failed (rather than the input being invalid).
    pub fn is_device(&self) -> bool {
        matches!(self, Self::Device(_))
    }
}
