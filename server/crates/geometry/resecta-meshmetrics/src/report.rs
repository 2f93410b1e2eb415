//! Markdown tables in the layout of the thesis' Tables 6.2–6.4, plus one row per model.

use std::fmt::Write;

use resecta_geom::Real;

use crate::study::{ModelMethod, ModelScore, Study};

impl ModelMethod {
    /// Short description of the method and its parameters, e.g. `PSR d = 7`.
    pub fn describe(&self) -> String {
        match self {
            Self::Psr { depth } => format!("PSR d = {depth}"),
            Self::Mcsd {
                smoothing,
                decimation,
            } => format!("MCSD s = {smoothing}, e = {decimation}"),
            Self::External { name } => name.clone(),
        }
    }
}

/// Wraps the cells at `bold` in `**`.
fn row(head: &str, cells: &[String], bold: Option<usize>) -> String {
    let mut s = format!("| {head} |");
    for (i, c) in cells.iter().enumerate() {
        if Some(i) == bold {
            let _ = write!(s, " **{c}** |");
        } else {
            let _ = write!(s, " {c} |");
        }
    }
    s.push('\n');
    s
}

fn header(cells: &[String]) -> String {
    let mut s = row("", cells, None);
    s.push_str(&"|---".repeat(cells.len() + 1));
    s.push_str("|\n");
    s
}

/// Index of the least value (first on ties).
fn least(values: &[Real]) -> Option<usize> {
    values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(i, _)| i)
}

impl Study {
    /// PSR models ordered by depth (then input order).
    fn psr_by_depth(&self) -> Vec<&ModelScore> {
        let mut psr: Vec<(u32, &ModelScore)> = self
            .models
            .iter()
            .filter_map(|m| match m.record.method {
                ModelMethod::Psr { depth } => Some((depth, m)),
                ModelMethod::Mcsd { .. } | ModelMethod::External { .. } => None,
            })
            .collect();
        psr.sort_by_key(|(d, _)| *d);
        psr.into_iter().map(|(_, m)| m).collect()
    }

    /// The study as Markdown: Tables 6.2 (σ of every PSR depth and the best MCSD), 6.3 (polygons,
    /// mean error and σ of ∂P_best, ∂C_sim, ∂C_best), 6.4 (mean Gaussian curvature of every PSR
    /// depth, ∂C_sim, ∂C_best) and a table of all models. Least values are in bold; tables whose
    /// models are missing say so.
    pub fn markdown(&self) -> String {
        let psr = self.psr_by_depth();
        let c_best = self.model(self.c_best);
        let c_sim = self.model(self.c_sim);
        let p_best = self.model(self.p_best);
        let depth = |m: &ModelScore| match m.record.method {
            ModelMethod::Psr { depth } => format!("d = {depth}"),
            ModelMethod::Mcsd { .. } | ModelMethod::External { .. } => m.record.label.clone(),
        };
        let mut s = String::new();

        s.push_str("### Objective score σ of all PSR and the best MCSD models (Table 6.2)\n\n");
        let mut cols: Vec<&ModelScore> = psr.clone();
        cols.extend(c_best);
        if cols.is_empty() {
            s.push_str("No PSR or MCSD models.\n\n");
        } else {
            let mut heads: Vec<String> = psr.iter().map(|m| format!("PSR {}", depth(m))).collect();
            heads.extend(c_best.map(|m| format!("Best MCSD ({})", m.record.method.describe())));
            let sig: Vec<Real> = cols.iter().map(|m| m.sigma).collect();
            s.push_str(&header(&heads));
            let cells: Vec<String> = sig.iter().map(|v| format!("{v:.3}")).collect();
            s.push_str(&row("σ", &cells, least(&sig)));
            s.push('\n');
        }

        s.push_str(
            "### Polygons, mean error and σ of the best PSR, the most similar MCSD and the best \
             MCSD (Table 6.3)\n\n",
        );
        let picks: Vec<(&str, &ModelScore)> = [
            ("I: best PSR ∂P_best", p_best),
            ("II: most similar MCSD ∂C_sim", c_sim),
            ("III: best MCSD ∂C_best", c_best),
        ]
        .into_iter()
        .filter_map(|(n, m)| m.map(|m| (n, m)))
        .collect();
        if picks.is_empty() {
            s.push_str("No PSR or MCSD models.\n\n");
        } else {
            let heads: Vec<String> = picks
                .iter()
                .map(|(n, m)| format!("{n} ({})", m.record.method.describe()))
                .collect();
            s.push_str(&header(&heads));
            let polys: Vec<Real> = picks.iter().map(|(_, m)| m.record.polys as Real).collect();
            let mean: Vec<Real> = picks.iter().map(|(_, m)| m.record.mean_mm).collect();
            let sig: Vec<Real> = picks.iter().map(|(_, m)| m.sigma).collect();
            let fmt = |v: &[Real], f: &dyn Fn(Real) -> String| -> Vec<String> {
                v.iter().map(|&x| f(x)).collect()
            };
            s.push_str(&row(
                "Polygons (K)",
                &fmt(&polys, &|x| format!("{:.1}", x / 1000.0)),
                least(&polys),
            ));
            s.push_str(&row(
                "Mean error (mm)",
                &fmt(&mean, &|x| format!("{x:.2}")),
                least(&mean),
            ));
            s.push_str(&row(
                "Objective score σ",
                &fmt(&sig, &|x| format!("{x:.2}")),
                least(&sig),
            ));
            s.push('\n');
        }

        s.push_str(
            "### Mean Gaussian curvature K̄ (5–95 percentiles, ×10⁻³ mm⁻²) of all PSR, the most \
             similar MCSD and the best MCSD (Table 6.4)\n\n",
        );
        let mut cols: Vec<(String, &ModelScore)> = psr
            .iter()
            .map(|m| (format!("PSR {}", depth(m)), *m))
            .collect();
        cols.extend(c_sim.map(|m| ("Similar MCSD".to_owned(), m)));
        cols.extend(c_best.map(|m| ("Best MCSD".to_owned(), m)));
        if cols.is_empty() {
            s.push_str("No PSR or MCSD models.\n\n");
        } else {
            let heads: Vec<String> = cols.iter().map(|(h, _)| h.clone()).collect();
            let k: Vec<Real> = cols.iter().map(|(_, m)| m.record.curvature).collect();
            let abs: Vec<Real> = k.iter().map(|v| v.abs()).collect();
            s.push_str(&header(&heads));
            let cells: Vec<String> = k.iter().map(|v| format!("{:.2}", v * 1e3)).collect();
            s.push_str(&row("K̄", &cells, least(&abs)));
            s.push('\n');
        }

        s.push_str("### All models\n\n");
        s.push_str(
            "| Label | Method | Polygons | Points | Mean (mm) | p95 (mm) | Max (mm) | \
             K̄ (×10⁻³ mm⁻²) | Time (ms) | δ̂ | N̂ | σ | Pareto | Selected |\n",
        );
        s.push_str(&"|---".repeat(14));
        s.push_str("|\n");
        for (i, m) in self.models.iter().enumerate() {
            let r = &m.record;
            let tags: Vec<&str> = [
                (Some(self.m_best), "∂M_best"),
                (self.p_best, "∂P_best"),
                (self.c_best, "∂C_best"),
                (self.c_sim, "∂C_sim"),
            ]
            .into_iter()
            .filter(|(j, _)| *j == Some(i))
            .map(|(_, t)| t)
            .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.0} | {:.3} | {:.3} | \
                 {:.3} | {} | {} |",
                r.label.replace('|', "\\|"),
                r.method.describe().replace('|', "\\|"),
                r.polys,
                r.points,
                r.mean_mm,
                r.p95_mm,
                r.max_mm,
                r.curvature * 1e3,
                r.time_ms,
                m.delta_hat,
                m.n_hat,
                m.sigma,
                if m.pareto { "yes" } else { "" },
                tags.join(", "),
            );
        }
        s
    }
}
