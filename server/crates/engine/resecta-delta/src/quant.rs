//! Quantisation: positions as u16 codes over a per-axis box, normals as octahedral snorm16 pairs.

use crate::format::{MAX_U16_CODE, NAN_U16, ZERO_OCT};

/// Per-axis box of u16 position codes: value = min + code · step (evaluated in f64, then
/// rounded to f32); code `NAN_U16` is a non-finite coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuantBox {
    pub min: [f32; 3],
    pub step: [f32; 3],
}

impl QuantBox {
    /// The box of the finite coordinates of `points`, with the step rounded up so that the
    /// largest coordinate gets a code ≤ `MAX_U16_CODE`.
    pub fn of<'a>(points: impl Iterator<Item = &'a [f32; 3]>) -> Self {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in points {
            for k in 0..3 {
                if p[k].is_finite() {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        let mut min = [0.0; 3];
        let mut step = [0.0; 3];
        for k in 0..3 {
            if lo[k] > hi[k] {
                continue; // no finite coordinate on this axis
            }
            min[k] = lo[k];
            let extent = f64::from(hi[k]) - f64::from(lo[k]);
            let mut s = (extent / f64::from(MAX_U16_CODE)) as f32;
            while f64::from(s) * f64::from(MAX_U16_CODE) < extent {
                s = s.next_up();
            }
            step[k] = s;
        }
        Self { min, step }
    }

    pub fn encode(&self, p: &[f32; 3]) -> [u16; 3] {
        std::array::from_fn(|k| {
            let v = p[k];
            if !v.is_finite() {
                return NAN_U16;
            }
            let step = f64::from(self.step[k]);
            if step == 0.0 {
                return 0;
            }
            let q = ((f64::from(v) - f64::from(self.min[k])) / step).round();
            q.clamp(0.0, f64::from(MAX_U16_CODE)) as u16
        })
    }

    pub fn decode(&self, q: [u16; 3]) -> [f32; 3] {
        std::array::from_fn(|k| {
            if q[k] == NAN_U16 {
                f32::NAN
            } else {
                (f64::from(self.min[k]) + f64::from(q[k]) * f64::from(self.step[k])) as f32
            }
        })
    }
}

const SNORM: f32 = 32767.0;

fn sign_not_zero(v: f32) -> f32 {
    if v < 0.0 { -1.0 } else { 1.0 }
}

/// Octahedral decode of a snorm16 pair to a unit normal (`ZERO_OCT` pair → zero vector).
pub fn oct_decode(q: [i16; 2]) -> [f32; 3] {
    if q == [ZERO_OCT, ZERO_OCT] {
        return [0.0; 3];
    }
    let mut x = (f32::from(q[0]) / SNORM).max(-1.0);
    let mut y = (f32::from(q[1]) / SNORM).max(-1.0);
    let z = 1.0 - x.abs() - y.abs();
    if z < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sign_not_zero(ox);
        y = (1.0 - ox.abs()) * sign_not_zero(oy);
    }
    let len = (x * x + y * y + z * z).sqrt();
    [x / len, y / len, z / len]
}

/// Octahedral encode of a normal (normalised first): of the four snorm16 pairs around the
/// exact projection, the one whose decoded direction is closest. Zero-length or non-finite
/// normals become the `ZERO_OCT` pair.
pub fn oct_encode(n: &[f32; 3]) -> [i16; 2] {
    let [x, y, z] = n.map(f64::from);
    let l1 = x.abs() + y.abs() + z.abs();
    if !(l1.is_finite() && l1 > 0.0) {
        return [ZERO_OCT, ZERO_OCT];
    }
    let (mut u, mut v) = (x / l1, y / l1);
    if z < 0.0 {
        let (ou, ov) = (u, v);
        u = (1.0 - ov.abs()) * if ou < 0.0 { -1.0 } else { 1.0 };
        v = (1.0 - ou.abs()) * if ov < 0.0 { -1.0 } else { 1.0 };
    }
    let s = f64::from(SNORM);
    let (fu, fv) = ((u * s).floor(), (v * s).floor());
    let len = (x * x + y * y + z * z).sqrt();
    let mut best = [0i16; 2];
    let mut best_dot = f64::NEG_INFINITY;
    for (du, dv) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let q = [(fu + du).clamp(-s, s) as i16, (fv + dv).clamp(-s, s) as i16];
        // Cosine of the angle, both vectors normalised in f64 (the decoded one's f32 length
        // error is larger than 1 − cos of the angles compared here).
        let d = oct_decode(q).map(f64::from);
        let dlen = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let dot = (d[0] * x + d[1] * y + d[2] * z) / (len * dlen);
        if dot > best_dot {
            best_dot = dot;
            best = q;
        }
    }
    best
}
