//! Arbitrary traces and deformations never panic: they make a surface or a named error, and a
//! surface's samples are finite.

use proptest::prelude::*;
use resecta_geom::{CutSurface, Real};
use resecta_traces::{CpSurface, Deformation, DsSurface};

fn coord() -> impl Strategy<Value = Real> {
    prop_oneof![
        8 => -200.0..200.0f64,
        1 => Just(0.0),
        1 => prop::sample::select(vec![Real::NAN, Real::INFINITY, 1e9, -1e-300]),
    ]
}

/// Traces mostly on axial slices (so DS gets past the orientation check), sometimes anywhere.
fn traces() -> impl Strategy<Value = Vec<Vec<[Real; 3]>>> {
    prop::collection::vec(
        (
            prop::collection::vec((coord(), coord(), coord()), 0..12),
            -60.0..60.0f64,
            prop::bool::weighted(0.8),
        )
            .prop_map(|(pts, z, flat)| {
                pts.into_iter()
                    .map(|(x, y, w)| [x, y, if flat { z } else { w }])
                    .collect()
            }),
        0..7,
    )
}

fn check(s: &dyn CutSurface) {
    let (mut p, mut n) = (Vec::new(), Vec::new());
    s.sample(9, 7, &mut p, &mut n);
    assert!(p.iter().all(|q| q.iter().all(|c| c.is_finite())));
    assert!(n.iter().all(|q| q.iter().all(|c| c.is_finite())));
    assert!(s.speeds().iter().all(|l| l.is_finite() && *l >= 0.0));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn ds_makes_a_finite_surface_or_an_error(t in traces()) {
        if let Ok(s) = DsSurface::new(&t) {
            check(&s);
        }
    }

    #[test]
    fn cp_makes_a_finite_surface_or_an_error(
        t in traces(),
        d in prop::collection::vec((coord(), coord(), coord(), coord(), coord()), 0..3),
    ) {
        let d: Vec<Deformation> = d
            .into_iter()
            .map(|(x, y, z, o, r)| Deformation { point: [x, y, z], offset_mm: o, radius_mm: r })
            .collect();
        if let Ok(s) = CpSurface::new(&t, &d) {
            check(&s);
        }
    }
}
