//! The point-cloud targets' check: a reader returns Ok or a typed error, never panics or hangs;
//! an accepted cloud is 1 to MAX_POINTS finite points (normals one each, finite, non-zero) and
//! round-trips through its own writer bit for bit.

use resecta_io::{MAX_POINTS, PointFormat, points_to_bytes, read_points_bytes};

fn bits(v: &[resecta_geom::Vec3]) -> Vec<[u64; 3]> {
    v.iter()
        .map(|p| [p.x, p.y, p.z].map(f64::to_bits))
        .collect()
}

pub fn check(data: &[u8], format: PointFormat, name: &str) {
    let Ok(cloud) = read_points_bytes(data, format, name) else {
        return;
    };
    assert!((1..=MAX_POINTS).contains(&cloud.len()));
    assert!(cloud.positions.iter().flatten().all(|c| c.is_finite()));
    if let Some(n) = &cloud.normals {
        assert_eq!(n.len(), cloud.len());
        assert!(
            n.iter()
                .all(|v| v.iter().all(|c| c.is_finite()) && v.iter().any(|&c| c != 0.0))
        );
    }
    let bytes = points_to_bytes(&cloud, format, name).expect("an accepted cloud is written");
    let back = read_points_bytes(&bytes, format, name).expect("a written cloud is read");
    assert_eq!(bits(&back.positions), bits(&cloud.positions));
    assert_eq!(
        back.normals.as_deref().map(bits),
        cloud.normals.as_deref().map(bits)
    );
}
