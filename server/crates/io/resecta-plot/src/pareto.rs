//! The accuracy–complexity figure of Paper I (thesis Fig. 6.7).

use std::collections::BTreeMap;

use resecta_meshmetrics::{ModelMethod, Study};

use crate::figure::{Colour, Figure, MarkerShape, Series, Style};

/// Mean point-to-surface distance against polygon count (log scale): every PSR model (labelled
/// with its depth unless highlighted), every MCSD model, each external method, the Pareto front as a line, and
/// ∂P_best, ∂C_best and ∂C_sim highlighted and labelled (one marker with joined names when two
/// selections are the same model; the legend gives each one's method and parameters). 1000 × 700 pixels.
pub fn pareto_figure(study: &Study) -> Figure {
    let xy = |i: usize| {
        let r = &study.models[i].record;
        (r.polys as f64, r.mean_mm)
    };
    let mut psr = Series::new(
        "PSR",
        Vec::new(),
        Style::Markers {
            shape: MarkerShape::Circle,
            colour: Colour::BLUE,
        },
    );
    let mut mcsd = Series::new(
        "MCSD",
        Vec::new(),
        Style::Markers {
            shape: MarkerShape::Triangle,
            colour: Colour::ORANGE,
        },
    );
    let picked = [study.p_best, study.c_best, study.c_sim];
    let mut external: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, m) in study.models.iter().enumerate() {
        match &m.record.method {
            ModelMethod::Psr { depth } => {
                psr.points.push(xy(i));
                // Highlighted models carry their own label.
                psr.labels
                    .push((!picked.contains(&Some(i))).then(|| format!("d = {depth}")));
            }
            ModelMethod::Mcsd { .. } => mcsd.points.push(xy(i)),
            ModelMethod::External { name } => external.entry(name).or_default().push(i),
        }
    }
    let mut series: Vec<Series> = [psr, mcsd]
        .into_iter()
        .filter(|s| !s.points.is_empty())
        .collect();
    series.extend(external.into_iter().map(|(name, idx)| {
        Series::new(
            name,
            idx.into_iter().map(xy).collect(),
            Style::Markers {
                shape: MarkerShape::Square,
                colour: Colour::GREY,
            },
        )
    }));
    series.push(Series::new(
        "Pareto front",
        study.pareto_front.iter().map(|&i| xy(i)).collect(),
        Style::Line {
            colour: Colour::BLACK,
        },
    ));
    // Selections, merged where they name the same model.
    let mut picks: Vec<(usize, Vec<&str>)> = Vec::new();
    for (index, name) in [
        (study.p_best, "∂P_best"),
        (study.c_best, "∂C_best"),
        (study.c_sim, "∂C_sim"),
    ] {
        let Some(i) = index else { continue };
        match picks.iter_mut().find(|(j, _)| *j == i) {
            Some((_, names)) => names.push(name),
            None => picks.push((i, vec![name])),
        }
    }
    let looks = [
        (MarkerShape::Circle, Colour::GREEN),
        (MarkerShape::Square, Colour::RED),
        (MarkerShape::Triangle, Colour::PURPLE),
    ];
    for ((i, names), (shape, colour)) in picks.into_iter().zip(looks) {
        let label = names.join(" = ");
        let name = format!("{label}: {}", study.models[i].record.method.describe());
        series.push(Series {
            labels: vec![Some(label)],
            ..Series::new(
                name,
                vec![xy(i)],
                Style::HighlightedMarkers { shape, colour },
            )
        });
    }
    Figure {
        title: "Accuracy and complexity of surface models".into(),
        x_label: "Polygons".into(),
        y_label: "Mean point-to-surface distance (mm)".into(),
        log_x: true,
        series,
        width: 1000,
        height: 700,
    }
}
