//! Unoriented point clouds, such as the points a mapping catheter collects on the left atrium
//! (thesis ch. 9): the normals and areas that Poisson reconstruction needs.
//!
//! [`estimate_normals`] works in four steps:
//! 1. **Neighbours.** The `k` nearest neighbours of every distinct position (a k-d tree;
//!    exact duplicates share one normal).
//! 2. **Normals.** Each normal is the least principal axis of the point and its neighbours
//!    (local PCA, Hoppe et al. 1992).
//! 3. **Orientation.** The symmetric k-nearest-neighbour graph gets a minimum spanning
//!    forest, along which each normal is turned to agree with its parent's. Agreement is
//!    judged after mirroring the parent's normal in the plane normal to the chord,
//!    `r(n) = n − 2(n·ê)ê`. On a circle through both points, that mirror image is the normal
//!    at the other end (König & Gumhold 2009). This keeps sparse points on a tube consistent
//!    where their normals differ by 90° or more. An edge costs `(1 − |r(nᵢ)·nⱼ|) +
//!    ½(|ê·nᵢ| + |ê·nⱼ|)`. The second term is small only along both tangent planes, so edges
//!    that jump a gap come last. Each tree's overall sign is then fixed by the divergence
//!    theorem: outward normals of a closed surface have `Σ aᵢ nᵢ·(pᵢ − c) = 3·volume > 0`
//!    for any shape.
//! 4. **Areas.** A point stands for `π r² / (k + 1)` mm², where `r` is the distance to its
//!    k-th neighbour. This is the local density in the k-neighbourhood disc, so clouds that
//!    are denser in one region are weighted fairly.
//!
//! Pure geometry: no I/O; rayon over points; the result does not depend on the thread count.

use std::collections::VecDeque;
use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use resecta_geom::{Pca, Real, Vec3};

/// Fewest distinct positions [`estimate_normals`] accepts.
pub const MIN_POINTS: usize = 4;
/// Default neighbourhood size: enough for a stable plane fit on 100–600 catheter points,
/// small enough not to reach across a pulmonary vein at that density.
pub const DEFAULT_NEIGHBOURS: usize = 10;
/// Smallest neighbourhood accepted (a plane fit needs the point and two others).
pub const MIN_NEIGHBOURS: usize = 3;
/// Weight of the tangent terms in an orientation edge's cost (see the crate doc); 0.5 gave the
/// fewest flips on sparse draws from the atrium phantom (0, 0.5 and 1 tried).
const TANGENT_WEIGHT: Real = 0.5;
/// Largest neighbourhood accepted.
pub const MAX_NEIGHBOURS: usize = 64;

/// What can go wrong estimating normals.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PointCloudError {
    #[error("point {index} is not finite")]
    NonFinite { index: usize },
    #[error("{got} distinct points given, at least {needed} needed")]
    TooFewPoints { needed: usize, got: usize },
    #[error("neighbours {got} out of range: 3..={max} and fewer than the distinct points")]
    Neighbours { got: usize, max: usize },
    #[error("all points lie on one line: no surface normal is defined")]
    Collinear,
}

/// Parameters of [`estimate_normals`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalParams {
    /// `k`: neighbours per point for the plane fit, the orientation graph and the areas.
    pub neighbours: usize,
}

impl Default for NormalParams {
    fn default() -> Self {
        Self {
            neighbours: DEFAULT_NEIGHBOURS,
        }
    }
}

/// Normals and areas of a cloud, one per input point, and how the orientation went.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalEstimate {
    /// Unit normals, oriented outward (see the crate doc).
    pub normals: Vec<Vec3>,
    /// Surface area each point stands for, mm².
    pub areas: Vec<Real>,
    /// Connected components of the neighbour graph, each oriented from its own root.
    pub components: usize,
    /// Distinct positions (exact duplicates are merged).
    pub distinct: usize,
    /// Points whose neighbourhood is (nearly) collinear; their normals are their tree
    /// parent's.
    pub degenerate: usize,
    /// Median distance to the nearest other point, mm.
    pub spacing_mm: Real,
}

/// Outward unit normals and areas of `positions` (see the crate doc).
pub fn estimate_normals(
    positions: &[Vec3],
    params: &NormalParams,
) -> Result<NormalEstimate, PointCloudError> {
    let hood = Neighbourhoods::new(positions, params.neighbours)?;
    let (unique, neighbours) = (&hood.unique, &hood.near);
    let n = unique.len();
    let fits: Vec<(Vec3, bool)> = (0..n)
        .into_par_iter()
        .map(|i| plane_normal(unique, i, &neighbours[i]))
        .collect();
    if fits.iter().all(|&(_, degenerate)| degenerate) {
        return Err(PointCloudError::Collinear);
    }
    let areas: Vec<Real> = (0..n).map(|u| hood.area(u)).collect();
    let (mut normals, components) = orient(unique, neighbours, &areas, fits.iter().map(|f| f.0));
    let mut degenerate = 0;
    for &(parent, child) in &components.tree_edges {
        if fits[child].1 {
            normals[child] = normals[parent];
            degenerate += 1;
        }
    }
    let mut nearest_other: Vec<Real> = neighbours
        .iter()
        .map(|nb| nb.first().map_or(0.0, |&(_, d)| d))
        .collect();
    nearest_other.sort_unstable_by(Real::total_cmp);
    Ok(NormalEstimate {
        normals: hood.of_input.iter().map(|&u| normals[u]).collect(),
        areas: hood.of_input.iter().map(|&u| hood.area(u)).collect(),
        components: components.count,
        distinct: n,
        degenerate,
        spacing_mm: nearest_other[n / 2],
    })
}

/// Areas as in [`estimate_normals`], for points that come with their normals, and the number
/// of distinct positions.
pub fn point_areas(
    positions: &[Vec3],
    neighbours: usize,
) -> Result<(Vec<Real>, usize), PointCloudError> {
    let hood = Neighbourhoods::new(positions, neighbours)?;
    let areas = hood.of_input.iter().map(|&u| hood.area(u)).collect();
    Ok((areas, hood.unique.len()))
}

/// Distinct positions, each input point's distinct index and the neighbours of each.
struct Neighbourhoods {
    unique: Vec<Vec3>,
    of_input: Vec<usize>,
    k: usize,
    /// The `k` nearest other distinct points of each, with distances, nearest first.
    near: Vec<Vec<(usize, Real)>>,
}

impl Neighbourhoods {
    fn new(positions: &[Vec3], k: usize) -> Result<Self, PointCloudError> {
        if let Some(index) = positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(PointCloudError::NonFinite { index });
        }
        let (unique, of_input) = merge_duplicates(positions);
        let n = unique.len();
        if n < MIN_POINTS {
            return Err(PointCloudError::TooFewPoints {
                needed: MIN_POINTS,
                got: n,
            });
        }
        if !(MIN_NEIGHBOURS..=MAX_NEIGHBOURS).contains(&k) || k >= n {
            return Err(PointCloudError::Neighbours {
                got: k,
                max: MAX_NEIGHBOURS.min(n - 1),
            });
        }
        let near = nearest(&unique, k);
        Ok(Self {
            unique,
            of_input,
            k,
            near,
        })
    }

    /// `π r² / (k + 1)`, `r` the distance to the k-th neighbour.
    fn area(&self, u: usize) -> Real {
        let r = self.near[u].last().map_or(0.0, |&(_, d)| d);
        std::f64::consts::PI * r * r / (self.k + 1) as Real
    }
}

/// Distinct positions (in input order) and, per input point, the index of its distinct position.
fn merge_duplicates(positions: &[Vec3]) -> (Vec<Vec3>, Vec<usize>) {
    let key = |i: usize| positions[i].map(|c| c.to_bits());
    let mut order: Vec<usize> = (0..positions.len()).collect();
    order.sort_unstable_by_key(|&i| (key(i).x, key(i).y, key(i).z, i));
    // Each point's representative: the first input point at its position.
    let mut rep = vec![0; positions.len()];
    for r in 0..order.len() {
        let i = order[r];
        rep[i] = if r > 0 && key(order[r - 1]) == key(i) {
            rep[order[r - 1]]
        } else {
            i
        };
    }
    let mut unique = Vec::new();
    let mut index_of = vec![0; positions.len()];
    for i in 0..positions.len() {
        if rep[i] == i {
            index_of[i] = unique.len();
            unique.push(positions[i]);
        }
    }
    let of_input = rep.iter().map(|&r| index_of[r]).collect();
    (unique, of_input)
}

/// The `k` nearest other points of every point with their distances, nearest first.
fn nearest(points: &[Vec3], k: usize) -> Vec<Vec<(usize, Real)>> {
    let coords: Vec<[Real; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree: ImmutableKdTree<Real, 3> = ImmutableKdTree::new_from_slice(&coords);
    let want = NonZero::new(k + 1).unwrap_or(NonZero::<usize>::MIN);
    coords
        .par_iter()
        .enumerate()
        .map(|(i, q)| {
            let mut found: Vec<(usize, Real)> = tree
                .nearest_n::<SquaredEuclidean>(q, want)
                .into_iter()
                .filter_map(|nb| {
                    let j = usize::try_from(nb.item).ok()?;
                    (j != i).then_some((j, nb.distance.sqrt()))
                })
                .collect();
            found.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            found.truncate(k);
            found
        })
        .collect()
}

/// Least principal axis of `points[i]` and its neighbours, and whether the fit is degenerate
/// (the neighbourhood nearly collinear).
fn plane_normal(points: &[Vec3], i: usize, neighbours: &[(usize, Real)]) -> (Vec3, bool) {
    let mut hood = Vec::with_capacity(neighbours.len() + 1);
    hood.push(points[i]);
    hood.extend(neighbours.iter().map(|&(j, _)| points[j]));
    match Pca::of_points(&hood) {
        Ok(pca) => {
            let [l0, l1, _] = pca.eigenvalues;
            (pca.axes[2], !(l1 > 1e-9 * l0 && l0 > 0.0))
        }
        Err(_) => (Vec3::z(), true),
    }
}

/// The spanning forest: its edges as (parent, child) in visiting order, and its tree count.
struct Forest {
    tree_edges: Vec<(usize, usize)>,
    count: usize,
}

/// Consistently oriented normals over the minimum spanning forest of the neighbour graph.
fn orient(
    points: &[Vec3],
    neighbours: &[Vec<(usize, Real)>],
    areas: &[Real],
    normals: impl Iterator<Item = Vec3>,
) -> (Vec<Vec3>, Forest) {
    let mut normals: Vec<Vec3> = normals.collect();
    let n = points.len();
    let mut edges: Vec<(Real, usize, usize)> = Vec::with_capacity(n * neighbours[0].len());
    for (i, nb) in neighbours.iter().enumerate() {
        for &(j, d) in nb {
            let (a, b) = (i.min(j), i.max(j));
            let e = if d > 0.0 {
                (points[b] - points[a]) / d
            } else {
                Vec3::zeros()
            };
            let (na, nbn) = (normals[a], normals[b]);
            let agree = reflect(na, e).dot(&nbn);
            let cost =
                (1.0 - agree.abs()) + TANGENT_WEIGHT * (e.dot(&na).abs() + e.dot(&nbn).abs());
            edges.push((cost, a, b));
        }
    }
    edges.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    edges.dedup_by(|x, y| x.1 == y.1 && x.2 == y.2);
    // Kruskal.
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut adjacency: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &(_, a, b) in &edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
            adjacency[a].push(b);
            adjacency[b].push(a);
        }
    }
    // Components and their roots (the point farthest from the centroid: any start works, the
    // sign is fixed afterwards).
    let mut component = vec![usize::MAX; n];
    let mut members: Vec<Vec<usize>> = Vec::new();
    for s in 0..n {
        if component[s] != usize::MAX {
            continue;
        }
        let c = members.len();
        let mut list = vec![s];
        component[s] = c;
        let mut head = 0;
        while head < list.len() {
            let v = list[head];
            head += 1;
            for &w in &adjacency[v] {
                if component[w] == usize::MAX {
                    component[w] = c;
                    list.push(w);
                }
            }
        }
        members.push(list);
    }
    let mut tree_edges = Vec::with_capacity(n);
    let mut seen = vec![false; n];
    for list in &members {
        let centroid = list.iter().map(|&v| points[v]).sum::<Vec3>() / list.len() as Real;
        let root = list
            .iter()
            .copied()
            .max_by(|&a, &b| {
                (points[a] - centroid)
                    .norm_squared()
                    .total_cmp(&(points[b] - centroid).norm_squared())
                    .then(b.cmp(&a))
            })
            .unwrap_or(list[0]);
        seen[root] = true;
        let mut queue = VecDeque::from([root]);
        while let Some(v) = queue.pop_front() {
            for &w in &adjacency[v] {
                if !seen[w] {
                    seen[w] = true;
                    let d = points[w] - points[v];
                    let e = if d.norm() > 0.0 {
                        d.normalize()
                    } else {
                        Vec3::zeros()
                    };
                    if normals[w].dot(&reflect(normals[v], e)) < 0.0 {
                        normals[w] = -normals[w];
                    }
                    tree_edges.push((v, w));
                    queue.push_back(w);
                }
            }
        }
    }
    // Global sign per component: for a closed surface with outward normals
    // ∮ n·(p − c) dA = 3·volume > 0 (divergence theorem), whatever its shape.
    for list in &members {
        let centroid = list.iter().map(|&v| points[v]).sum::<Vec3>() / list.len() as Real;
        let flux: Real = list
            .iter()
            .map(|&v| areas[v] * normals[v].dot(&(points[v] - centroid)))
            .sum();
        if flux < 0.0 {
            for &v in list {
                normals[v] = -normals[v];
            }
        }
    }
    (
        normals,
        Forest {
            tree_edges,
            count: members.len(),
        },
    )
}

/// `n` mirrored in the plane normal to the unit chord `e`: the normal at the chord's other end
/// if both ends lie on one circle (König & Gumhold 2009's consistency for curved patches).
fn reflect(n: Vec3, e: Vec3) -> Vec3 {
    n - e * (2.0 * n.dot(&e))
}
