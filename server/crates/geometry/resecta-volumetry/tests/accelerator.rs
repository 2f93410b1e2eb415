//! The accelerator seam: a plain reference accelerator written from the contract in
//! `resecta_volumetry::accel` gives the CPU's results bit for bit (volumes, incomplete cuts,
//! label maps, unions); a failing one falls back to the CPU, counted.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use resecta_bezier::ControlNet;
use resecta_geom::{Grid, Real, Vec3, Volume};
use resecta_volumetry::{
    AcceleratorError, BandComponents, BandQuery, BandVoxel, CutAccelerator, LiverVoxels, Volumetry,
};

/// The contract, voxel by voxel: band by every sample's slab-disc (smallest (f32 d², index)),
/// components by union–find over face neighbours rooted at the smallest compact index.
#[derive(Debug, Default)]
struct Reference {
    /// Component root per compact index of the last cut (`u32::MAX` in the band).
    root: Vec<u32>,
    calls: usize,
}

fn find(p: &mut [u32], mut a: u32) -> u32 {
    while p[a as usize] != a {
        a = p[a as usize];
    }
    a
}

impl CutAccelerator for Reference {
    fn band_components(
        &mut self,
        liver: &LiverVoxels,
        q: &BandQuery<'_>,
    ) -> Result<BandComponents, AcceleratorError> {
        self.calls += 1;
        let [bx, by, bz] = liver.bdims();
        let lo = liver.box_lo();
        let index = liver.box_index();
        let grid = liver.grid();
        let mut best: Vec<Option<(f32, u32)>> = vec![None; index.len()];
        for (k, d) in q.discs.iter().enumerate() {
            let [o1, o2] = d.outer_axes();
            for a in d.outer[0][0]..=d.outer[0][1] {
                for b in d.outer[1][0]..=d.outer[1][1] {
                    let (c0, c1) = d.column(q.hs, a, b, liver.bdims()[d.axis]);
                    for c in c0..=c1 {
                        let mut ijk = [0usize; 3];
                        (ijk[d.axis], ijk[o1], ijk[o2]) = (c as usize, a as usize, b as usize);
                        let cell = ijk[0] + bx * (ijk[1] + by * ijk[2]);
                        if index[cell] == u32::MAX {
                            continue;
                        }
                        let centre = grid.voxel_center([0, 1, 2].map(|i| ijk[i] + lo[i]));
                        if let Some((d2, _)) = d.reach(&centre, q.rho) {
                            let cand = (d2, k as u32);
                            let slot = &mut best[cell];
                            if slot.is_none_or(|s| cand < s) {
                                *slot = Some(cand);
                            }
                        }
                    }
                }
            }
        }
        let n = liver.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let free = |cell: usize| index[cell] != u32::MAX && best[cell].is_none();
        let step = [1, bx, bx * by];
        let dims = [bx, by, bz];
        for cell in (0..index.len()).filter(|&c| free(c)) {
            let xyz = [cell % bx, (cell / bx) % by, cell / (bx * by)];
            for a in 0..3 {
                if xyz[a] + 1 < dims[a] && free(cell + step[a]) {
                    let (ra, rb) = (
                        find(&mut parent, index[cell]),
                        find(&mut parent, index[cell + step[a]]),
                    );
                    parent[ra.max(rb) as usize] = ra.min(rb);
                }
            }
        }
        self.root = vec![u32::MAX; n];
        let mut roots = Vec::new();
        for cell in (0..index.len()).filter(|&c| free(c)) {
            let r = find(&mut parent, index[cell]);
            self.root[index[cell] as usize] = r;
            if r == index[cell] {
                roots.push(r);
            }
        }
        let mut band = Vec::new();
        for (cell, b) in best.iter().enumerate() {
            let Some((_, sample)) = b else { continue };
            let xyz = [cell % bx, (cell / bx) % by, cell / (bx * by)];
            let mut neighbours = [u32::MAX; 6];
            for a in 0..3 {
                for (s, ok) in [(0, xyz[a] > 0), (1, xyz[a] + 1 < dims[a])] {
                    let nb = if s == 0 {
                        cell.wrapping_sub(step[a])
                    } else {
                        cell + step[a]
                    };
                    if ok && free(nb) {
                        neighbours[2 * a + s] = find(&mut parent, index[nb]);
                    }
                }
            }
            band.push(BandVoxel {
                cell: cell as u32,
                sample: *sample,
                neighbours,
            });
        }
        // Any order is allowed: hand them over reversed.
        band.reverse();
        roots.reverse();
        Ok(BandComponents { band, roots })
    }

    fn resected_mask(&mut self, roots: &[u32]) -> Result<Vec<u32>, AcceleratorError> {
        let mut mask = vec![0u32; self.root.len().div_ceil(32)];
        for (c, r) in self.root.iter().enumerate() {
            if *r != u32::MAX && roots.binary_search(r).is_ok() {
                mask[c / 32] |= 1 << (c % 32);
            }
        }
        Ok(mask)
    }
}

/// Fails every call.
#[derive(Debug)]
struct Broken;

impl CutAccelerator for Broken {
    fn band_components(
        &mut self,
        _: &LiverVoxels,
        _: &BandQuery<'_>,
    ) -> Result<BandComponents, AcceleratorError> {
        Err(AcceleratorError("device lost".into()))
    }
    fn resected_mask(&mut self, _: &[u32]) -> Result<Vec<u32>, AcceleratorError> {
        Err(AcceleratorError("device lost".into()))
    }
}

fn oblique_grid(spacing: [Real; 3], half: Real) -> Grid {
    let dir = nalgebra::Rotation3::from_euler_angles(0.12, -0.08, 0.2).into_inner();
    let dims = spacing.map(|s| (2.0 * half / s).ceil() as usize + 1);
    let half_extent = Vec3::from_fn(|i, _| spacing[i] * (dims[i] - 1) as Real / 2.0);
    Grid::new(
        dims,
        spacing,
        Vec3::new(0.3, -0.2, 0.1) - dir * half_extent,
        dir,
    )
    .unwrap()
}

fn mask(grid: &Grid, inside: impl Fn(Vec3) -> bool) -> Volume<bool> {
    let data = (0..grid.len())
        .map(|v| inside(grid.voxel_center(grid.ijk(v))))
        .collect();
    Volume::from_vec(grid.clone(), data).unwrap()
}

/// An ellipsoid liver with a detached island, and a ring-shaped one (leaks).
fn livers() -> Vec<Volume<bool>> {
    let g = oblique_grid([1.3, 1.0, 2.0], 48.0);
    let ellipsoid = |p: Vec3| {
        (p.x / 40.0).powi(2) + (p.y / 30.0).powi(2) + (p.z / 25.0).powi(2) <= 1.0
            || (p - Vec3::new(-38.0, 30.0, 20.0)).norm() <= 5.0
    };
    let ring = |p: Vec3| ((p.x * p.x + p.y * p.y).sqrt() - 32.0).powi(2) + p.z * p.z <= 100.0;
    vec![mask(&g, ellipsoid), mask(&g, ring)]
}

fn cuts() -> Vec<(ControlNet<Real>, Vec<Vec3>)> {
    let t = vec![Vec3::new(30.0, 0.0, 0.0)];
    let planar =
        |o: [Real; 3], u: [Real; 3], v: [Real; 3]| ControlNet::planar(4, 4, o, u, v).unwrap();
    let bent = ControlNet::from_fn(4, 4, |i, j| {
        let (u, v) = (i as Real / 3.0, j as Real / 3.0);
        [
            5.0 + 12.0 * (u - 0.5) * (v - 0.4),
            -60.0 + 120.0 * u,
            -60.0 + 120.0 * v,
        ]
    })
    .unwrap();
    vec![
        // Complete, oblique.
        (
            planar([10.0, -60.0, -60.0], [-8.0, 120.0, 0.0], [6.0, 0.0, 120.0]),
            t.clone(),
        ),
        // Curved.
        (bent, t.clone()),
        // Ends inside the liver.
        (
            planar([5.0, -10.0, -10.0], [0.0, 20.0, 0.0], [0.0, 0.0, 20.0]),
            t.clone(),
        ),
        // Misses it.
        (
            planar([70.0, -60.0, -60.0], [0.0, 120.0, 0.0], [0.0, 0.0, 120.0]),
            t.clone(),
        ),
        // Through one arm of the ring only.
        (
            planar([20.0, 0.0, -20.0], [30.0, 0.0, 0.0], [0.0, 0.0, 40.0]),
            vec![Vec3::new(32.0, 6.0, 0.0)],
        ),
    ]
}

#[test]
fn the_reference_accelerator_gives_the_cpu_results_bit_for_bit() {
    for (li, m) in livers().iter().enumerate() {
        let mut cpu = Volumetry::new(LiverVoxels::new(m).unwrap());
        let mut acc = Volumetry::new(LiverVoxels::new(m).unwrap())
            .with_accelerator(Box::<Reference>::default());
        assert!(acc.is_accelerated());
        let cuts = cuts();
        for (k, (net, t)) in cuts.iter().enumerate() {
            let (a, b) = (cpu.cut(net, t).unwrap(), acc.cut(net, t).unwrap());
            eprintln!("liver {li} cut {k}: {b:?}");
            assert_eq!(a, b, "liver {li} cut {k}");
        }
        let pairs: Vec<(&dyn resecta_geom::CutSurface, &[Vec3])> =
            cuts.iter().map(|(n, t)| (n as _, t.as_slice())).collect();
        let two = &pairs[..2];
        assert_eq!(cpu.cuts(two).unwrap(), acc.cuts(two).unwrap());
        assert_eq!(
            cpu.resected_labels(&pairs).unwrap(),
            acc.resected_labels(&pairs).unwrap()
        );
        assert_eq!(
            acc.accelerator_fallbacks().0,
            0,
            "{:?}",
            acc.accelerator_fallbacks()
        );
    }
}

#[test]
fn a_failing_accelerator_falls_back_to_the_cpu() {
    let m = &livers()[0];
    let mut cpu = Volumetry::new(LiverVoxels::new(m).unwrap());
    let mut acc = Volumetry::new(LiverVoxels::new(m).unwrap()).with_accelerator(Box::new(Broken));
    for (net, t) in &cuts()[..2] {
        assert_eq!(cpu.cut(net, t).unwrap(), acc.cut(net, t).unwrap());
    }
    let (n, e) = acc.accelerator_fallbacks();
    assert_eq!(n, 2);
    assert_eq!(
        e.map(ToString::to_string).as_deref(),
        Some("volumetry accelerator: device lost")
    );
    assert!(acc.set_accelerator(None).is_some());
    assert!(!acc.is_accelerated());
}

/// The reference with its output spoiled one way: a far sample, no roots, a duplicate voxel.
#[derive(Debug, Default)]
struct Spoiled(Reference, u8);

impl CutAccelerator for Spoiled {
    fn band_components(
        &mut self,
        liver: &LiverVoxels,
        q: &BandQuery<'_>,
    ) -> Result<BandComponents, AcceleratorError> {
        let mut bc = self.0.band_components(liver, q)?;
        match self.1 {
            0 => {
                bc.band[0].sample =
                    (bc.band[0].sample + q.discs.len() as u32 / 2) % q.discs.len() as u32
            }
            1 => bc.roots.clear(),
            _ => bc.band.push(bc.band[0]),
        }
        Ok(bc)
    }
    fn resected_mask(&mut self, roots: &[u32]) -> Result<Vec<u32>, AcceleratorError> {
        self.0.resected_mask(roots)
    }
}

#[test]
fn spoiled_accelerator_output_falls_back_to_the_cpu() {
    let m = &livers()[0];
    let (net, t) = &cuts()[0];
    let want = Volumetry::new(LiverVoxels::new(m).unwrap())
        .cut(net, t)
        .unwrap();
    for how in 0..3 {
        let mut acc = Volumetry::new(LiverVoxels::new(m).unwrap())
            .with_accelerator(Box::new(Spoiled(Reference::default(), how)));
        assert_eq!(acc.cut(net, t).unwrap(), want);
        let (n, e) = acc.accelerator_fallbacks();
        eprintln!("spoiled {how}: {e:?}");
        assert_eq!(n, 1);
        assert!(e.is_some_and(|e| e.0.starts_with("invalid accelerator output")));
    }
}
