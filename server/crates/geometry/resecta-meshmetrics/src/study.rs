//! Accuracy–complexity study over a set of models (Eq. 6.10–6.12, 6.14) and the Pareto front.

use std::collections::BTreeSet;

use resecta_geom::Real;

use crate::error::MetricsError;

/// How a model was made. PSR models form the thesis' set 𝒫, MCSD models the set 𝒞; `External`
/// models (another program's output, e.g. a reference reconstruction) belong to neither.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ModelMethod {
    /// Poisson surface reconstruction at octree/grid depth `depth`.
    Psr {
        depth: u32,
    },
    /// Marching cubes, smoothing and decimation with Paper I's parameters.
    Mcsd {
        smoothing: Real,
        decimation: Real,
    },
    External {
        name: String,
    },
}

/// One model's measurements.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModelRecord {
    /// Unique name of the model in the study (used in the tables).
    pub label: String,
    pub method: ModelMethod,
    /// Triangle count.
    pub polys: usize,
    /// Vertex count.
    pub points: usize,
    /// Point-to-surface distance from the reference cloud (Eq. 6.9): mean, p95, max, in mm.
    pub mean_mm: Real,
    pub p95_mm: Real,
    pub max_mm: Real,
    /// Mean Gaussian curvature over the 5–95 percentile band (Eq. 6.13), 1/mm².
    pub curvature: Real,
    /// Wall time to build the model, ms.
    pub time_ms: Real,
}

/// A record with its place in objective space.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModelScore {
    pub record: ModelRecord,
    /// Normalised mean distance δ̂ ∈ [0, 1] (Eq. 6.10).
    pub delta_hat: Real,
    /// Normalised complexity N̂ ∈ [0, 1] (Eq. 6.10), from the polygon count.
    pub n_hat: Real,
    /// Objective score σ = √(δ̂² + N̂²) (Eq. 6.11).
    pub sigma: Real,
    /// Not dominated in (polygons, mean distance) by any other model.
    pub pareto: bool,
}

/// The study of Paper I over one label map. Indices refer to [`Study::models`], which keeps the
/// input order.
///
/// Normalisation (Eq. 6.10) takes its extremes over all models, PSR, MCSD and external alike (the
/// thesis normalises over all models of a parenchyma; pass only PSR and MCSD records to reproduce
/// it exactly). N is the polygon count, as in the thesis' figures and Table 6.3 (the text of
/// Eq. 6.10 says points). When all models share a value, its normalised value is 0 for all.
/// Ties in an arg min go to the first model in input order.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Study {
    pub models: Vec<ModelScore>,
    /// Models on the Pareto front (minimising polygons and mean distance), by polygon count.
    pub pareto_front: Vec<usize>,
    /// ∂P_best: least σ among PSR models (Eq. 6.12); `None` without PSR models.
    pub p_best: Option<usize>,
    /// ∂C_best: least σ among MCSD models; `None` without MCSD models.
    pub c_best: Option<usize>,
    /// ∂M_best: least σ among all models.
    pub m_best: usize,
    /// ∂C_sim: the MCSD model whose mean curvature is closest to ∂P_best's (Eq. 6.14); `None`
    /// without PSR or without MCSD models.
    pub c_sim: Option<usize>,
}

impl Study {
    /// The model at `index`, if any (convenience for the `Option` fields).
    pub fn model(&self, index: Option<usize>) -> Option<&ModelScore> {
        index.and_then(|i| self.models.get(i))
    }
}

fn check(r: &ModelRecord) -> Result<(), MetricsError> {
    let bad = |field| MetricsError::BadRecord {
        label: r.label.clone(),
        field,
    };
    let fields = [
        ("mean_mm", r.mean_mm),
        ("p95_mm", r.p95_mm),
        ("max_mm", r.max_mm),
        ("time_ms", r.time_ms),
    ];
    if let Some((name, _)) = fields.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
        return Err(bad(name));
    }
    if !r.curvature.is_finite() {
        return Err(bad("curvature"));
    }
    if let ModelMethod::Mcsd {
        smoothing,
        decimation,
    } = r.method
    {
        if !(smoothing.is_finite() && smoothing >= 0.0) {
            return Err(bad("smoothing"));
        }
        if !(decimation.is_finite() && decimation >= 0.0) {
            return Err(bad("decimation"));
        }
    }
    Ok(())
}

/// `(x − min) / (max − min)` for every `x`; all 0 when the values are equal.
fn normalise(values: &[Real]) -> Vec<Real> {
    let lo = values.iter().copied().fold(Real::INFINITY, Real::min);
    let hi = values.iter().copied().fold(Real::NEG_INFINITY, Real::max);
    let range = hi - lo;
    values
        .iter()
        .map(|&v| if range > 0.0 { (v - lo) / range } else { 0.0 })
        .collect()
}

/// First index of the least `key` among the models accepted by `keep`.
fn argmin(
    models: &[ModelScore],
    keep: impl Fn(&ModelMethod) -> bool,
    key: impl Fn(&ModelScore) -> Real,
) -> Option<usize> {
    models
        .iter()
        .enumerate()
        .filter(|(_, m)| keep(&m.record.method))
        .fold(None, |best: Option<(usize, Real)>, (i, m)| {
            let k = key(m);
            match best {
                Some((_, b)) if b <= k => best,
                _ => Some((i, k)),
            }
        })
        .map(|(i, _)| i)
}

/// Scores every record and selects the best models (see [`Study`]). Errors on an empty list, a
/// repeated label, or a non-finite or negative measurement.
pub fn analyse(records: Vec<ModelRecord>) -> Result<Study, MetricsError> {
    if records.is_empty() {
        return Err(MetricsError::NoRecords);
    }
    let mut labels = BTreeSet::new();
    for r in &records {
        check(r)?;
        if !labels.insert(r.label.as_str()) {
            return Err(MetricsError::DuplicateLabel(r.label.clone()));
        }
    }
    let delta = normalise(&records.iter().map(|r| r.mean_mm).collect::<Vec<_>>());
    let polys = normalise(&records.iter().map(|r| r.polys as Real).collect::<Vec<_>>());
    let front = pareto_front(
        &records
            .iter()
            .map(|r| (r.polys as Real, r.mean_mm))
            .collect::<Vec<_>>(),
    );
    let mut models: Vec<ModelScore> = records
        .into_iter()
        .zip(delta.into_iter().zip(polys))
        .map(|(record, (d, n))| ModelScore {
            record,
            delta_hat: d,
            n_hat: n,
            sigma: d.hypot(n),
            pareto: false,
        })
        .collect();
    for &i in &front {
        models[i].pareto = true;
    }
    let is_psr = |m: &ModelMethod| matches!(m, ModelMethod::Psr { .. });
    let is_mcsd = |m: &ModelMethod| matches!(m, ModelMethod::Mcsd { .. });
    let sigma = |m: &ModelScore| m.sigma;
    let p_best = argmin(&models, is_psr, sigma);
    let c_best = argmin(&models, is_mcsd, sigma);
    let m_best = argmin(&models, |_| true, sigma).ok_or(MetricsError::NoRecords)?;
    let c_sim = p_best.and_then(|p| {
        let target = models[p].record.curvature;
        argmin(&models, is_mcsd, |m| (m.record.curvature - target).abs())
    });
    Ok(Study {
        models,
        pareto_front: front,
        p_best,
        c_best,
        m_best,
        c_sim,
    })
}

/// Indices of the points not dominated by another point when minimising both coordinates (a point
/// is dominated by one that is no worse in both and better in one; exact duplicates are all kept),
/// sorted by first coordinate, then second, then index. Points with a NaN coordinate are never on
/// the front and do not dominate. O(n log n).
pub fn pareto_front(points: &[(Real, Real)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| !points[i].0.is_nan() && !points[i].1.is_nan())
        .collect();
    order.sort_by(|&a, &b| {
        let (pa, pb) = (points[a], points[b]);
        pa.0.total_cmp(&pb.0)
            .then(pa.1.total_cmp(&pb.1))
            .then(a.cmp(&b))
    });
    // In this order the front's second coordinate strictly decreases (duplicates aside); the last
    // front point has the least second coordinate seen so far.
    let mut front: Vec<usize> = Vec::new();
    for i in order {
        let p = points[i];
        let keep = match front.last() {
            None => true,
            Some(&j) => p.1 < points[j].1 || p == points[j],
        };
        if keep {
            front.push(i);
        }
    }
    front
}
