//! The resectogram: a resection surface unrolled to its (u, v) square, coloured by margin
//! class, with the liver boundary, the portal territories it passes through, the vessels it
//! cuts and its worst point (Slicer-Liver's view of a cut, from the planner's own samples).

use rayon::prelude::*;
use resecta_geom::Real;
use resecta_margin::{MarginClass, MarginSettings};
use resecta_vessels::VesselSystem;
use serde::Serialize;

use crate::engine::Planner;
use crate::error::PlanError;
use crate::vascular::{CutMesh, CutVessel, TERRITORY_GENERATION, cut_vessels, liver_crossings};

/// Largest resectogram side in pixels.
pub const MAX_SIDE: usize = 512;

/// A resection's resectogram. Pixel `(i, j)` (row-major, `j·width + i`) shows the surface at
/// `u = (i + ½)/width`, `v = (j + ½)/height`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Resectogram {
    pub resection: String,
    pub width: usize,
    pub height: usize,
    /// [`MarginClass`] per pixel (0 outside the liver, 1 safe, 2 warning, 3 violation): the
    /// liver boundary is where 0 meets the rest. Distances and inside levels are interpolated
    /// bilinearly between the surface samples.
    pub classes: Vec<u8>,
    /// Portal territory per pixel: 1 + the branch (of generation ≤ 2, see
    /// [`TERRITORY_GENERATION`]) feeding the liver there; 0 outside the liver or without a
    /// portal tree.
    pub territories: Vec<u32>,
    /// The vessels this resection cuts, with their (u, v).
    pub cut_vessels: Vec<CutVessel>,
    /// Where the margin is smallest inside the liver.
    pub worst_uv: Option<[Real; 2]>,
    pub min_margin_mm: Option<Real>,
    pub margin_mm: Real,
    pub band_mm: Real,
}

/// Where pixel centres fall between the samples along one axis of `n` samples: the lower
/// sample, the weight of the upper one, and the nearest sample, for each of `pixels`.
fn axis_weights(pixels: usize, n: usize) -> Vec<(usize, Real, usize)> {
    (0..pixels)
        .map(|i| {
            let x = (i as Real + 0.5) / pixels as Real * (n - 1) as Real;
            let lo = (x.floor() as usize).min(n.saturating_sub(2));
            (lo, x - lo as Real, (x.round() as usize).min(n - 1))
        })
        .collect()
}

/// Bilinear interpolation of per-sample values (sample `a·rv + b`) between samples `a0..=a0+1`
/// and `b0..=b0+1`; non-finite corners are left out (the nearest corner's value when all
/// weights vanish).
fn bilinear(values: &[Real], rv: usize, (a0, fa): (usize, Real), (b0, fb): (usize, Real)) -> Real {
    let (a1, b1) = ((a0 + 1).min(values.len() / rv - 1), (b0 + 1).min(rv - 1));
    let corners = [
        (a0 * rv + b0, (1.0 - fa) * (1.0 - fb)),
        (a1 * rv + b0, fa * (1.0 - fb)),
        (a0 * rv + b1, (1.0 - fa) * fb),
        (a1 * rv + b1, fa * fb),
    ];
    let (mut sum, mut w) = (0.0, 0.0);
    let mut nearest = (Real::NEG_INFINITY, Real::INFINITY);
    for (k, wt) in corners {
        let x = values[k];
        if x.is_finite() {
            sum += wt * x;
            w += wt;
        }
        if wt > nearest.0 {
            nearest = (wt, x);
        }
    }
    if w > 1e-12 { sum / w } else { nearest.1 }
}

impl Planner {
    /// The resectogram of resection `name` at `width`×`height` pixels (each 1..=[`MAX_SIDE`]).
    pub fn resectogram(
        &self,
        name: &str,
        width: usize,
        height: usize,
    ) -> Result<Resectogram, PlanError> {
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(PlanError::InvalidArgument(format!(
                "resectogram size {width}×{height}: each side must be 1..={MAX_SIDE} pixels"
            )));
        }
        let r = self
            .plan()
            .resections
            .iter()
            .find(|r| r.name == name)
            .ok_or_else(|| PlanError::UnknownResection(name.to_owned()))?;
        let state = self.state(name)?;
        let settings = MarginSettings {
            margin_mm: r.margin_mm,
            band_mm: r.band_mm,
        };
        let [ru, rv] = state.surface.resolution();
        let anatomy = self.anatomy();
        let model = anatomy.vascular().model();
        // Per sample: the territory (portal), then per pixel: class and nearest sample's territory.
        let points = state.surface.points();
        let sample_territory: Vec<u32> = match model {
            Some(m) => points
                .par_iter()
                .zip(&state.inside)
                .map(|(p, &ins)| {
                    if ins > 0.0 {
                        m.territory_at(VesselSystem::Portal, p, TERRITORY_GENERATION)
                            .map_or(0, |t| t as u32 + 1)
                    } else {
                        0
                    }
                })
                .collect(),
            None => vec![0; points.len()],
        };
        let (cols, rows) = (axis_weights(width, ru), axis_weights(height, rv));
        let mut classes = vec![0u8; width * height];
        let mut territories = vec![0u32; width * height];
        classes
            .par_chunks_mut(width)
            .zip(territories.par_chunks_mut(width))
            .zip(rows.par_iter())
            .for_each(|((class_row, territory_row), &(b0, fb, nb))| {
                for (i, &(a0, fa, na)) in cols.iter().enumerate() {
                    let d = bilinear(&state.margins.distance, rv, (a0, fa), (b0, fb));
                    let ins = bilinear(&state.inside, rv, (a0, fa), (b0, fb));
                    let class = settings.classify(d, ins);
                    class_row[i] = class as u8;
                    if class != MarginClass::Outside {
                        territory_row[i] = sample_territory[na * rv + nb];
                    }
                }
            });
        let cut_vessels = match model {
            Some(m) => {
                let surface = [CutMesh {
                    name: name.to_owned(),
                    mesh: state.surface.mesh()?,
                    resolution: [ru, rv],
                }];
                let x = liver_crossings(anatomy, m, &surface)?;
                cut_vessels(&m.cut_branches(&x), &surface)
            }
            None => Vec::new(),
        };
        Ok(Resectogram {
            resection: name.to_owned(),
            width,
            height,
            classes,
            territories,
            cut_vessels,
            worst_uv: state.verdict.uv,
            min_margin_mm: state.verdict.min_margin_mm,
            margin_mm: r.margin_mm,
            band_mm: r.band_mm,
        })
    }
}

/// RGB of a margin class, as the 3D views colour it (outside light grey).
pub const CLASS_RGB: [[u8; 3]; 4] = [
    [219, 219, 219],
    [158, 158, 158],
    [255, 217, 0],
    [230, 13, 13],
];
const PORTAL_RGB: [u8; 3] = [40, 90, 220];
const HEPATIC_RGB: [u8; 3] = [130, 50, 170];

impl Resectogram {
    /// The picture, `scale` screen pixels per resectogram pixel: class colours, territories
    /// shaded alternately and outlined, the liver boundary in black, cut vessels as discs
    /// (portal blue, hepatic purple; radius ∝ the vessel's) and the worst point as a magenta
    /// cross. RGBA, row-major, row 0 at v = 0.
    pub fn to_rgba(&self, scale: usize) -> (usize, usize, Vec<u8>) {
        let scale = scale.clamp(1, 8);
        let (w, h) = (self.width * scale, self.height * scale);
        let mut px = vec![255u8; w * h * 4];
        let at = |x: usize, y: usize| (y / scale) * self.width + x / scale;
        let put = |px: &mut [u8], x: usize, y: usize, rgb: [u8; 3]| {
            let o = (y * w + x) * 4;
            px[o..o + 3].copy_from_slice(&rgb);
        };
        for y in 0..h {
            for x in 0..w {
                let k = at(x, y);
                let c = usize::from(self.classes[k]).min(3);
                let mut rgb = CLASS_RGB[c];
                let t = self.territories[k];
                if t > 0 && t.is_multiple_of(2) {
                    rgb = rgb.map(|v| (f32::from(v) * 0.88) as u8);
                }
                // Boundaries: a pixel with a 4-neighbour on the other side (drawn on both).
                let inside = self.classes[k] > 0;
                let neighbours = [
                    (x > 0).then(|| at(x - 1, y)),
                    (x + 1 < w).then(|| at(x + 1, y)),
                    (y > 0).then(|| at(x, y - 1)),
                    (y + 1 < h).then(|| at(x, y + 1)),
                ];
                let mut territory_edge = false;
                for k2 in neighbours.into_iter().flatten() {
                    if (self.classes[k2] > 0) != inside {
                        rgb = [0, 0, 0];
                    } else if self.territories[k2] != t {
                        territory_edge = true;
                    }
                }
                if territory_edge && rgb != [0, 0, 0] {
                    rgb = [70, 70, 70];
                }
                put(&mut px, x, y, rgb);
            }
        }
        let to_px = |uv: [Real; 2]| (uv[0] * w as Real, uv[1] * h as Real);
        for c in &self.cut_vessels {
            let (cx, cy) = to_px(c.uv);
            let r = (c.radius_mm * scale as Real).clamp(3.0, 12.0 * scale as Real);
            let rgb = if c.system == "hepatic" {
                HEPATIC_RGB
            } else {
                PORTAL_RGB
            };
            for y in (cy - r - 1.0).max(0.0) as usize..((cy + r + 2.0) as usize).min(h) {
                for x in (cx - r - 1.0).max(0.0) as usize..((cx + r + 2.0) as usize).min(w) {
                    let d =
                        ((x as Real + 0.5 - cx).powi(2) + (y as Real + 0.5 - cy).powi(2)).sqrt();
                    if d <= r {
                        put(&mut px, x, y, rgb);
                    } else if d <= r + 1.0 {
                        put(&mut px, x, y, [0, 0, 0]);
                    }
                }
            }
        }
        if let Some(uv) = self.worst_uv {
            let (cx, cy) = to_px(uv);
            let arm = 4 * scale as i64 + 3;
            for d in -arm..=arm {
                for (x, y) in [
                    (cx as i64 + d, cy as i64 + d),
                    (cx as i64 + d, cy as i64 - d),
                ] {
                    if (0..w as i64).contains(&x) && (0..h as i64).contains(&y) {
                        put(&mut px, x as usize, y as usize, [230, 0, 200]);
                    }
                }
            }
        }
        (w, h, px)
    }
}
