//! Topology-preserving decimation by edge collapse with quadric error metrics (Garland &
//! Heckbert 1997).
//!
//! Every vertex carries the sum of the area-weighted plane quadrics of its triangles (plus, on
//! open meshes, `boundary_weight`-weighted planes through each boundary edge perpendicular to
//! its triangle). An edge collapses into the quadric-optimal point — or, where that 3×3 system
//! is ill-conditioned or its solution lies far from the edge, the best of midpoint and
//! endpoints; an edge with exactly one boundary endpoint collapses onto that endpoint, so
//! boundaries stay where they are.
//!
//! Scheduling is by passes (as in meshoptimizer's simplifier, rather than one global priority
//! queue, which is several times slower on large meshes): each pass costs all edges in
//! parallel, sorts them by (cost, vertex indices) and walks them cheapest first up to the cost
//! of the `3·needed`-th edge, collapsing every admissible edge whose endpoints have not been
//! touched yet in this pass. A collapse is admissible unless
//! - the edge is used by one (boundary) or two triangles and neither endpoint touches a
//!   non-manifold edge or a degenerate triangle of the input;
//! - the link condition holds (the endpoints' common neighbours are exactly the apexes of the
//!   edge's triangles) and an interior edge does not join two boundary vertices;
//! - an interior apex keeps at least 3 triangles and a boundary apex at least 1, so no
//!   tetrahedron flattens into a double-sided triangle;
//! - no surviving triangle turns by more than `max_normal_change_deg` or becomes degenerate.
//!
//! Hence a watertight, manifold, consistently oriented input stays so. Collapses stop when the
//! triangle count reaches `round((1 − target_reduction)·n)` (interior collapses remove two
//! triangles, so it may end one below), when a pass without cost limit collapses nothing, or
//! after [`MAX_PASSES`] passes. The result is deterministic and independent of the thread count
//! (parallel steps only compute per-edge values, the collapses are sequential).

use std::cmp::Ordering;

use rayon::prelude::*;
use resecta_geom::{Mat3, Real, TriMesh, Vec3};

use crate::FilterError;

/// Most sorting passes before giving up on the target.
pub const MAX_PASSES: u32 = 200;

/// Parameters of [`decimate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecimateParams {
    /// Fraction of triangles to remove, in [0, 1); 0 returns the input unchanged.
    pub target_reduction: Real,
    /// Largest allowed rotation of a surviving triangle's normal in one collapse (degrees,
    /// (0, 180]); guards against fold-overs.
    pub max_normal_change_deg: Real,
    /// Weight of the boundary-preserving planes relative to the surface planes (≥ 0).
    pub boundary_weight: Real,
}

impl Default for DecimateParams {
    fn default() -> Self {
        Self {
            target_reduction: 0.0,
            max_normal_change_deg: 60.0,
            boundary_weight: 10.0,
        }
    }
}

impl DecimateParams {
    /// Slicer's decimation factor is the target reduction (its `vtkDecimatePro` feature angle
    /// of 60° is used here as the normal-change limit).
    pub fn slicer(decimation_factor: Real) -> Self {
        Self {
            target_reduction: decimation_factor,
            ..Self::default()
        }
    }

    fn validate(&self) -> Result<(), FilterError> {
        if !(0.0..1.0).contains(&self.target_reduction) {
            return Err(FilterError::BadTargetReduction(self.target_reduction));
        }
        if !(self.max_normal_change_deg > 0.0 && self.max_normal_change_deg <= 180.0) {
            return Err(FilterError::BadNormalChange(self.max_normal_change_deg));
        }
        if !(self.boundary_weight >= 0.0 && self.boundary_weight.is_finite()) {
            return Err(FilterError::BadBoundaryWeight(self.boundary_weight));
        }
        Ok(())
    }
}

/// What [`decimate_with_report`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecimateReport {
    pub input_triangles: usize,
    pub target_triangles: usize,
    pub output_triangles: usize,
    pub collapses: usize,
    /// Sorting passes over all edges.
    pub passes: u32,
}

/// Decimates `mesh` (see the module notes). Output vertices are compacted (original order of
/// the survivors), triangles keep their original order; normals and scalars are dropped.
pub fn decimate(mesh: &TriMesh, params: &DecimateParams) -> Result<TriMesh, FilterError> {
    decimate_with_report(mesh, params).map(|(m, _)| m)
}

/// [`decimate`] with counts of what happened.
pub fn decimate_with_report(
    mesh: &TriMesh,
    params: &DecimateParams,
) -> Result<(TriMesh, DecimateReport), FilterError> {
    params.validate()?;
    let n = mesh.triangles().len();
    let target = ((1.0 - params.target_reduction) * n as Real).round() as usize;
    let mut report = DecimateReport {
        input_triangles: n,
        target_triangles: target,
        output_triangles: n,
        collapses: 0,
        passes: 0,
    };
    if target >= n {
        return Ok((mesh.clone(), report));
    }
    let mut d = Decimator::new(mesh, params);
    d.run(target, &mut report);
    let out = d.output()?;
    report.output_triangles = out.triangles().len();
    Ok((out, report))
}

/// Symmetric 4×4 quadric `pᵀAp + 2b·p + c`.
#[derive(Debug, Clone, Copy, Default)]
struct Quadric {
    a: [Real; 6], // xx xy xz yy yz zz
    b: [Real; 3],
    c: Real,
}

impl Quadric {
    /// `w · (n·p + d)²`.
    fn plane(n: Vec3, d: Real, w: Real) -> Self {
        Self {
            a: [
                w * n.x * n.x,
                w * n.x * n.y,
                w * n.x * n.z,
                w * n.y * n.y,
                w * n.y * n.z,
                w * n.z * n.z,
            ],
            b: [w * d * n.x, w * d * n.y, w * d * n.z],
            c: w * d * d,
        }
    }
    fn add(&self, o: &Self) -> Self {
        Self {
            a: std::array::from_fn(|i| self.a[i] + o.a[i]),
            b: std::array::from_fn(|i| self.b[i] + o.b[i]),
            c: self.c + o.c,
        }
    }
    fn matrix(&self) -> Mat3 {
        let a = &self.a;
        Mat3::new(a[0], a[1], a[2], a[1], a[3], a[4], a[2], a[4], a[5])
    }
    fn eval(&self, p: &Vec3) -> Real {
        let a = &self.a;
        let quad = a[0] * p.x * p.x
            + a[3] * p.y * p.y
            + a[5] * p.z * p.z
            + 2.0 * (a[1] * p.x * p.y + a[2] * p.x * p.z + a[4] * p.y * p.z);
        (quad + 2.0 * (self.b[0] * p.x + self.b[1] * p.y + self.b[2] * p.z) + self.c).max(0.0)
    }
}

/// An admissible collapse of `v` into `u`.
struct Plan {
    u: usize,
    v: usize,
    position: Vec3,
}

struct Decimator {
    pos: Vec<Vec3>,
    quadric: Vec<Quadric>,
    tris: Vec<[u32; 3]>,
    tri_alive: Vec<bool>,
    /// Triangles around each vertex (may hold dead ones until cleaned).
    around: Vec<Vec<u32>>,
    boundary: Vec<bool>,
    /// Touches a non-manifold edge or a degenerate triangle of the input: never moved.
    locked: Vec<bool>,
    alive: Vec<bool>,
    /// Collapsed into or away during the current pass.
    touched: Vec<bool>,
    alive_tris: usize,
    cos_max: Real,
    area_eps: Real,
    // scratch
    nu: Vec<u32>,
    nv: Vec<u32>,
    /// Edges of the input (for the first pass).
    edges: Vec<(u32, u32)>,
}

impl Decimator {
    fn new(mesh: &TriMesh, params: &DecimateParams) -> Self {
        let pos = mesh.vertices().to_vec();
        let tris = mesh.triangles().to_vec();
        let nv = pos.len();
        let mut around: Vec<Vec<u32>> = vec![Vec::new(); nv];
        let mut locked = vec![false; nv];
        for (t, tri) in tris.iter().enumerate() {
            for &v in tri {
                around[v as usize].push(t as u32);
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                tri.iter().for_each(|&v| locked[v as usize] = true);
            }
        }
        // Undirected edge uses, sorted so equal edges are adjacent.
        let mut uses: Vec<(u32, u32, u32)> = tris
            .par_iter()
            .enumerate()
            .flat_map_iter(|(t, &[a, b, c])| {
                [(a, b), (b, c), (c, a)]
                    .into_iter()
                    .filter(|(p, q)| p != q)
                    .map(move |(p, q)| (p.min(q), p.max(q), t as u32))
            })
            .collect();
        uses.par_sort_unstable();
        let plane_quadrics: Vec<Quadric> = tris
            .par_iter()
            .map(|&[a, b, c]| {
                let (pa, pb, pc) = (pos[a as usize], pos[b as usize], pos[c as usize]);
                let cross = (pb - pa).cross(&(pc - pa));
                let area2 = cross.norm();
                if area2 > 0.0 {
                    let n = cross / area2;
                    Quadric::plane(n, -n.dot(&pa), 0.5 * area2)
                } else {
                    Quadric::default()
                }
            })
            .collect();
        let mut boundary = vec![false; nv];
        let mut edges = Vec::with_capacity(uses.len() / 2 + 1);
        let mut boundary_quadrics: Vec<(u32, Quadric)> = Vec::new();
        let mut i = 0;
        while i < uses.len() {
            let (a, b, t) = uses[i];
            let mut j = i + 1;
            while j < uses.len() && uses[j].0 == a && uses[j].1 == b {
                j += 1;
            }
            match j - i {
                1 => {
                    boundary[a as usize] = true;
                    boundary[b as usize] = true;
                    let [p, q, r] = tris[t as usize].map(|v| pos[v as usize]);
                    let (pa, pb) = (pos[a as usize], pos[b as usize]);
                    let normal = (q - p).cross(&(r - p));
                    if let Some(m) = (pb - pa).cross(&normal).try_normalize(0.0) {
                        let w = params.boundary_weight * (pb - pa).norm_squared();
                        let quadric = Quadric::plane(m, -m.dot(&pa), w);
                        boundary_quadrics.push((a, quadric));
                        boundary_quadrics.push((b, quadric));
                    }
                }
                2 => {}
                _ => {
                    locked[a as usize] = true;
                    locked[b as usize] = true;
                }
            }
            edges.push((a, b));
            i = j;
        }
        let mut quadric: Vec<Quadric> = around
            .par_iter()
            .map(|ts| {
                ts.iter().fold(Quadric::default(), |q, &t| {
                    q.add(&plane_quadrics[t as usize])
                })
            })
            .collect();
        for (v, q) in boundary_quadrics {
            quadric[v as usize] = quadric[v as usize].add(&q);
        }
        let diag = mesh.bounds().map_or(0.0, |(lo, hi)| (hi - lo).norm());
        let mut d = Self {
            pos,
            quadric,
            tri_alive: vec![true; tris.len()],
            alive_tris: tris.len(),
            tris,
            around,
            boundary,
            locked,
            alive: vec![true; nv],
            touched: vec![false; nv],
            cos_max: params.max_normal_change_deg.to_radians().cos(),
            area_eps: (diag * 1e-9).powi(2),
            nu: Vec::new(),
            nv: Vec::new(),
            edges: Vec::new(),
        };
        d.edges = edges;
        d
    }

    /// Where the collapse of edge (u, v) puts the merged vertex, and its quadric error.
    fn placement(&self, u: usize, v: usize) -> (Vec3, Real) {
        let q = self.quadric[u].add(&self.quadric[v]);
        let (pu, pv) = (self.pos[u], self.pos[v]);
        if self.boundary[u] != self.boundary[v] {
            let p = if self.boundary[u] { pu } else { pv };
            return (p, q.eval(&p));
        }
        let mid = (pu + pv) * 0.5;
        let a = q.matrix();
        let scale = a.norm();
        if scale > 0.0
            && a.determinant().abs() > 1e-9 * scale * scale * scale
            && let Some(inv) = a.try_inverse()
        {
            let p = -(inv * Vec3::new(q.b[0], q.b[1], q.b[2]));
            if p.iter().all(|c| c.is_finite()) && (p - mid).norm() <= (pu - pv).norm() {
                return (p, q.eval(&p));
            }
        }
        [mid, pu, pv]
            .into_iter()
            .map(|p| (p, q.eval(&p)))
            .fold(
                (mid, Real::INFINITY),
                |best, c| {
                    if c.1 < best.1 { c } else { best }
                },
            )
    }

    fn run(&mut self, target: usize, report: &mut DecimateReport) {
        let mut edges = std::mem::take(&mut self.edges);
        let mut capped = true;
        while self.alive_tris > target && report.passes < MAX_PASSES {
            if report.passes > 0 {
                edges = self.alive_edges();
            }
            report.passes += 1;
            let this = &*self;
            let mut costed: Vec<(Real, u32, u32)> = edges
                .par_iter()
                .filter(|&&(a, b)| !this.locked[a as usize] && !this.locked[b as usize])
                .map(|&(a, b)| (this.placement(a as usize, b as usize).1, a, b))
                .collect();
            costed.par_sort_unstable_by(|x, y| {
                x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2))
            });
            let needed = (self.alive_tris - target).div_ceil(2);
            let limit = match costed.get(3 * needed) {
                Some(c) if capped => c.0,
                _ => Real::INFINITY,
            };
            self.touched.fill(false);
            let before = report.collapses;
            for &(cost, u, v) in &costed {
                if cost > limit || self.alive_tris <= target {
                    break;
                }
                let (u, v) = (u as usize, v as usize);
                if self.touched[u] || self.touched[v] || !self.alive[u] || !self.alive[v] {
                    continue;
                }
                if let Some(plan) = self.check(u, v) {
                    self.apply(plan);
                    self.touched[u] = true;
                    self.touched[v] = true;
                    report.collapses += 1;
                }
            }
            if report.collapses == before {
                if !capped || limit == Real::INFINITY {
                    break;
                }
                capped = false;
            }
        }
    }

    fn alive_edges(&self) -> Vec<(u32, u32)> {
        let mut edges: Vec<(u32, u32)> = self
            .tris
            .par_iter()
            .zip(self.tri_alive.par_iter())
            .filter(|(_, alive)| **alive)
            .flat_map_iter(|(&[a, b, c], _)| {
                [(a, b), (b, c), (c, a)]
                    .into_iter()
                    .map(|(p, q)| (p.min(q), p.max(q)))
            })
            .collect();
        edges.par_sort_unstable();
        edges.dedup();
        edges
    }

    /// Sorted distinct neighbours of `v` (through alive triangles) into `out`.
    fn neighbours(&self, v: usize, out: &mut Vec<u32>) {
        out.clear();
        for &t in &self.around[v] {
            if self.tri_alive[t as usize] {
                out.extend(self.tris[t as usize].iter().filter(|&&w| w as usize != v));
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    fn alive_count(&self, v: usize) -> usize {
        self.around[v]
            .iter()
            .filter(|&&t| self.tri_alive[t as usize])
            .count()
    }

    fn check(&mut self, u: usize, v: usize) -> Option<Plan> {
        if self.locked[u] || self.locked[v] {
            return None;
        }
        // Triangles on the edge and their apexes.
        let mut apexes = [0u32; 2];
        let mut shared = 0;
        for &t in &self.around[u] {
            let tri = self.tris[t as usize];
            if self.tri_alive[t as usize] && tri.contains(&(v as u32)) {
                if shared == 2 {
                    return None;
                }
                apexes[shared] = tri
                    .into_iter()
                    .find(|&w| w as usize != u && w as usize != v)?;
                shared += 1;
            }
        }
        if shared == 0 || (shared == 2 && self.boundary[u] && self.boundary[v]) {
            return None;
        }
        // Link condition.
        let (mut nu, mut nv) = (std::mem::take(&mut self.nu), std::mem::take(&mut self.nv));
        self.neighbours(u, &mut nu);
        self.neighbours(v, &mut nv);
        let common = count_common(&nu, &nv);
        self.nu = nu;
        self.nv = nv;
        if common != shared || (shared == 2 && apexes[0] == apexes[1]) {
            return None;
        }
        for &w in &apexes[..shared] {
            let w = w as usize;
            let min = if self.boundary[w] { 2 } else { 4 };
            if self.alive_count(w) < min {
                return None;
            }
        }
        // Geometry: no fold-over, no degenerate triangle.
        let (p, _) = self.placement(u, v);
        for &x in &[u, v] {
            for &t in &self.around[x] {
                if !self.tri_alive[t as usize] {
                    continue;
                }
                let tri = self.tris[t as usize];
                if tri.contains(&(u as u32)) && tri.contains(&(v as u32)) {
                    continue;
                }
                let old = tri.map(|w| self.pos[w as usize]);
                let new = tri.map(|w| {
                    if w as usize == x {
                        p
                    } else {
                        self.pos[w as usize]
                    }
                });
                let n0 = (old[1] - old[0]).cross(&(old[2] - old[0]));
                let n1 = (new[1] - new[0]).cross(&(new[2] - new[0]));
                let l1 = n1.norm();
                if l1 <= self.area_eps || n0.dot(&n1) < self.cos_max * n0.norm() * l1 {
                    return None;
                }
            }
        }
        Some(Plan { u, v, position: p })
    }

    fn apply(&mut self, plan: Plan) {
        let Plan { u, v, position } = plan;
        let (u32_, v32) = (u as u32, v as u32);
        let mut apexes = Vec::with_capacity(2);
        for &t in &self.around[u] {
            let tri = &self.tris[t as usize];
            if self.tri_alive[t as usize] && tri.contains(&v32) {
                self.tri_alive[t as usize] = false;
                self.alive_tris -= 1;
                apexes.extend(tri.iter().copied().filter(|&w| w != u32_ && w != v32));
            }
        }
        let moved = std::mem::take(&mut self.around[v]);
        for &t in &moved {
            if self.tri_alive[t as usize] {
                for w in &mut self.tris[t as usize] {
                    if *w == v32 {
                        *w = u32_;
                    }
                }
                self.around[u].push(t);
            }
        }
        let tri_alive = &self.tri_alive;
        self.around[u].retain(|&t| tri_alive[t as usize]);
        for &w in &apexes {
            self.around[w as usize].retain(|&t| tri_alive[t as usize]);
        }
        self.pos[u] = position;
        self.quadric[u] = self.quadric[u].add(&self.quadric[v]);
        self.boundary[u] |= self.boundary[v];
        self.alive[v] = false;
    }

    fn output(&self) -> Result<TriMesh, FilterError> {
        let mut used = vec![false; self.pos.len()];
        for (t, tri) in self.tris.iter().enumerate() {
            if self.tri_alive[t] {
                tri.iter().for_each(|&w| used[w as usize] = true);
            }
        }
        let mut index = vec![u32::MAX; self.pos.len()];
        let mut vertices = Vec::new();
        for v in (0..self.pos.len()).filter(|&v| used[v]) {
            index[v] = vertices.len() as u32;
            vertices.push(self.pos[v]);
        }
        let mut triangles = Vec::with_capacity(self.alive_tris);
        for (t, tri) in self.tris.iter().enumerate() {
            if self.tri_alive[t] {
                triangles.push(tri.map(|w| index[w as usize]));
            }
        }
        Ok(TriMesh::new(vertices, triangles)?)
    }
}

/// Size of the intersection of two sorted lists.
fn count_common(a: &[u32], b: &[u32]) -> usize {
    let (mut i, mut j, mut n) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            Ordering::Less => i += 1,
            Ordering::Greater => j += 1,
            Ordering::Equal => {
                n += 1;
                i += 1;
                j += 1;
            }
        }
    }
    n
}
