#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The atrium phantom's truth checked against its own definition and closed forms.

use std::f64::consts::PI;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use resecta_geom::Real;
use resecta_phantom::atrium::ellipsoid_area;
use resecta_phantom::{
    Atrium, AtriumSpec, BODY_LABEL, GridSpec, Orientation, PhantomError, VEIN_LABELS, VeinSpec,
};

#[test]
fn ellipsoid_area_matches_closed_forms() {
    let r = 7.5;
    assert!((ellipsoid_area([r, r, r]) / (4.0 * PI * r * r) - 1.0).abs() < 1e-6);
    // Prolate spheroid a = b < c: 2πa²(1 + c/(a e) asin e), e² = 1 − a²/c².
    let (a, c): (Real, Real) = (10.0, 25.0);
    let e = (1.0 - a * a / (c * c)).sqrt();
    let exact = 2.0 * PI * a * a * (1.0 + c / (a * e) * e.asin());
    assert!((ellipsoid_area([a, c, a]) / exact - 1.0).abs() < 1e-6);
}

#[test]
fn samples_lie_on_the_union_with_outward_normals() {
    let atrium = Atrium::new(&AtriumSpec::standard()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let s = atrium.surface_samples(20_000, &mut rng);
    // 20 000 proposals over the parts by area; those inside another part (28 %) are dropped.
    assert!(s.positions.len() > 13_000 && s.positions.len() < 16_000);
    let solids: Vec<_> = std::iter::once(atrium.body())
        .chain(atrium.veins())
        .collect();
    for ((p, n), &part) in s.positions.iter().zip(&s.normals).zip(&s.part) {
        let own = solids[part as usize].signed_distance(*p);
        assert!(own.abs() < 1e-9, "sample off its part by {own}");
        assert!(solids.iter().all(|x| x.signed_distance(*p) > -1e-9));
        assert!((n.norm() - 1.0).abs() < 1e-12);
        // Just outside along the normal is outside the atrium, just inside is inside.
        assert!(!atrium.contains(p + n * 0.01) && atrium.contains(p - n * 0.01));
    }
    // Every vein keeps samples: its tube outside the body and its cap.
    for v in 1..=4u8 {
        assert!(s.part.iter().filter(|&&x| x == v).count() > 200);
    }
}

#[test]
fn ostia_lie_on_body_and_tube() {
    let atrium = Atrium::new(&AtriumSpec::standard()).unwrap();
    let ostia = atrium.ostia(64);
    assert_eq!(ostia.len(), 4);
    for (v, ring) in ostia.iter().enumerate() {
        assert_eq!(ring.len(), 64);
        for p in ring {
            assert!(atrium.body().signed_distance(*p).abs() < 1e-6);
            assert!(atrium.veins()[v].signed_distance(*p).abs() < 1e-6);
        }
    }
}

#[test]
fn label_map_has_lasc_labels_and_the_atrium_volume() {
    let atrium = Atrium::new(&AtriumSpec::standard()).unwrap();
    let grid = GridSpec::centred(
        [72, 50, 60],
        [1.25, 1.25, 1.37],
        [0.0, -6.0, 4.0],
        Orientation::default(),
    );
    let labels = atrium.label_map(&grid).unwrap();
    let counts = labels.value_counts();
    let voxel = 1.25 * 1.25 * 1.37;
    let body = counts[&BODY_LABEL] as Real * voxel;
    let exact = 4.0 / 3.0 * PI * 24.0 * 18.0 * 20.0;
    assert!((body / exact - 1.0).abs() < 0.01, "body {body} vs {exact}");
    for l in VEIN_LABELS {
        assert!(counts.get(&l).copied().unwrap_or(0) > 100, "vein label {l}");
    }
}

#[test]
fn misplaced_veins_are_refused() {
    let mut spec = AtriumSpec::standard();
    spec.veins[2] = VeinSpec {
        from: [0.0, 0.0, 30.0],
        to: [0.0, 0.0, 50.0],
        radius: 5.0,
    };
    assert_eq!(
        Atrium::new(&spec),
        Err(PhantomError::VeinPlacement { index: 2 })
    );
    spec.veins.clear();
    assert_eq!(Atrium::new(&spec), Err(PhantomError::VeinCount { got: 0 }));
    let mut spec = AtriumSpec::standard();
    spec.veins[0].radius = -1.0;
    assert!(matches!(
        Atrium::new(&spec),
        Err(PhantomError::NonPositive { .. })
    ));
}
