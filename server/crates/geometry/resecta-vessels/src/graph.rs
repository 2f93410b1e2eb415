//! Centreline graph of a skeleton, spur pruning, gap bridging, and the tree oriented from a root.

use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};

use resecta_geom::{Grid, Vec3, Volume};

use crate::error::VesselError;
use crate::skeleton::{Thinned, thin};

/// Parameters of [`vessel_tree`].
#[derive(Debug, Clone, PartialEq)]
pub struct VesselParams {
    /// Mask components (26-connected) with fewer voxels are specks: dropped and counted.
    pub min_component_voxels: usize,
    /// A terminal edge at a branch point is a spur, pruned, when it is shorter than
    /// `spur_factor · r + voxel diagonal` (`r` the radius at the branch point).
    pub spur_factor: f64,
    /// Largest gap bridged between an end of one fragment and a node of another, in mm, beyond
    /// the two radii (a tube's skeleton stops about one radius before its cap).
    pub max_gap_mm: f64,
}

impl Default for VesselParams {
    fn default() -> Self {
        Self {
            min_component_voxels: 20,
            spur_factor: 1.5,
            max_gap_mm: 2.0,
        }
    }
}

/// How the root of the tree is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RootChoice {
    /// The end point whose terminal edge has the largest median radius (the trunk).
    Auto,
    /// The graph node nearest this RAS point (mm).
    NearestTo(Vec3),
    /// One root per graph component, each chosen as by [`RootChoice::Auto`]: a forest, e.g. the
    /// hepatic veins entering the vena cava by several ostia. Nothing is detached.
    EveryComponent,
}

/// What a node of the tree is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeKind {
    Root,
    Branch,
    End,
}

/// A node: the root, a branch point or an end point.
#[derive(Debug, Clone, PartialEq)]
pub struct Node {
    pub id: usize,
    pub kind: NodeKind,
    /// RAS mm.
    pub position: Vec3,
    /// Radius in mm (largest over a junction's voxels).
    pub radius: f64,
}

/// An edge of the tree, oriented away from the root.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Index in [`VesselTree::edges`]; parents come before their children.
    pub id: usize,
    /// The edge this one leaves from (`None` at the root).
    pub parent: Option<usize>,
    pub children: Vec<usize>,
    /// Generation: 1 for edges leaving the root, parent's + 1 otherwise.
    pub generation: u32,
    /// Proximal node id.
    pub from: usize,
    /// Distal node id.
    pub to: usize,
    /// Centreline in RAS mm, from `from` to `to`.
    pub points: Vec<Vec3>,
    /// Radius in mm at each point.
    pub radii: Vec<f64>,
    pub length_mm: f64,
    /// Gaps between mask fragments bridged by straight segments inside this edge.
    pub bridged_gaps: usize,
}

/// What was dropped, joined or left out, so nothing is silent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TreeReport {
    /// Mask components below [`VesselParams::min_component_voxels`], dropped.
    pub specks: usize,
    pub speck_voxels: usize,
    /// Kept mask components.
    pub components: usize,
    pub skeleton_voxels: usize,
    pub spurs_pruned: usize,
    /// Gaps bridged between fragments.
    pub gaps_bridged: usize,
    /// Graph components not connected to the root's (left out of the tree).
    pub detached_components: usize,
    /// Mask voxels of the detached components.
    pub detached_voxels: usize,
    /// Edges closing a cycle in the root's component, left out of the tree.
    pub loop_edges_dropped: usize,
}

/// A vessel tree oriented from its root.
#[derive(Debug, Clone, PartialEq)]
pub struct VesselTree {
    pub grid: Grid,
    /// The first root (the widest trunk).
    pub root: usize,
    /// Every root node, widest trunk first (node ids `0..roots.len()`); one unless
    /// [`RootChoice::EveryComponent`].
    pub roots: Vec<usize>,
    pub nodes: Vec<Node>,
    pub edges: Vec<Edge>,
    pub report: TreeReport,
}

impl VesselTree {
    /// The edge and all its descendants.
    pub fn subtree(&self, edge: usize) -> Vec<usize> {
        let mut out = Vec::new();
        let mut stack = vec![edge];
        while let Some(e) = stack.pop() {
            if let Some(ed) = self.edges.get(e) {
                out.push(e);
                stack.extend(ed.children.iter().copied());
            }
        }
        out
    }
}

#[derive(Debug, Clone)]
struct RawNode {
    pos: Vec3,
    radius: f64,
    component: u32,
    alive: bool,
}

#[derive(Debug, Clone)]
struct RawEdge {
    a: usize,
    b: usize,
    points: Vec<Vec3>,
    radii: Vec<f64>,
    bridged: usize,
}

impl RawEdge {
    fn length(&self) -> f64 {
        self.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }
    fn other(&self, n: usize) -> usize {
        if self.a == n { self.b } else { self.a }
    }
    fn reversed(mut self) -> Self {
        std::mem::swap(&mut self.a, &mut self.b);
        self.points.reverse();
        self.radii.reverse();
        self
    }
}

#[derive(Debug, Clone, Default)]
struct RawGraph {
    nodes: Vec<RawNode>,
    edges: Vec<Option<RawEdge>>,
}

impl RawGraph {
    fn incidence(&self) -> Vec<Vec<usize>> {
        let mut inc = vec![Vec::new(); self.nodes.len()];
        for (i, e) in self.edges.iter().enumerate() {
            if let Some(e) = e {
                inc[e.a].push(i);
                inc[e.b].push(i);
            }
        }
        inc
    }

    /// Joins the two edges of every node of degree 2 into one.
    fn merge_degree_two(&mut self) {
        loop {
            let inc = self.incidence();
            let mut merged = false;
            for (n, list) in inc.iter().enumerate() {
                let &[i, j] = list.as_slice() else {
                    continue;
                };
                if !self.nodes[n].alive || i == j {
                    continue;
                }
                let (Some(e1), Some(e2)) = (self.edges[i].take(), self.edges[j].take()) else {
                    continue;
                };
                let e1 = if e1.b == n { e1 } else { e1.reversed() };
                let e2 = if e2.a == n { e2 } else { e2.reversed() };
                let mut points = e1.points;
                let mut radii = e1.radii;
                points.extend(e2.points.into_iter().skip(1));
                radii.extend(e2.radii.into_iter().skip(1));
                self.edges.push(Some(RawEdge {
                    a: e1.a,
                    b: e2.b,
                    points,
                    radii,
                    bridged: e1.bridged + e2.bridged,
                }));
                self.nodes[n].alive = false;
                merged = true;
                break;
            }
            if !merged {
                return;
            }
        }
    }

    /// Removes short terminal edges at branch points; returns how many.
    fn prune_spurs(&mut self, factor: f64, diag: f64) -> usize {
        let mut pruned = 0;
        loop {
            let inc = self.incidence();
            let mut removed = 0;
            for n in 0..self.nodes.len() {
                if !self.nodes[n].alive || inc[n].len() < 3 {
                    continue;
                }
                let limit = factor * self.nodes[n].radius + diag;
                let mut spurs: Vec<(usize, f64)> = inc[n]
                    .iter()
                    .filter_map(|&e| {
                        let edge = self.edges[e].as_ref()?;
                        let o = edge.other(n);
                        let len = edge.length();
                        (o != n && inc[o].len() == 1 && len < limit).then_some((e, len))
                    })
                    .collect();
                if spurs.len() == inc[n].len() {
                    // A star of short edges: the longest stays.
                    spurs.sort_by(|x, y| x.1.total_cmp(&y.1));
                    spurs.pop();
                }
                if spurs.is_empty() {
                    continue;
                }
                for (e, _) in spurs {
                    if let Some(edge) = self.edges[e].take() {
                        self.nodes[edge.other(n)].alive = false;
                        removed += 1;
                    }
                }
                // One branch point per pass: the incidence is stale afterwards.
                break;
            }
            if removed == 0 {
                return pruned;
            }
            pruned += removed;
            self.merge_degree_two();
        }
    }

    /// Union-find labels of graph components over alive nodes.
    fn components(&self) -> Vec<usize> {
        let mut parent: Vec<usize> = (0..self.nodes.len()).collect();
        fn find(p: &mut [usize], mut x: usize) -> usize {
            while p[x] != x {
                p[x] = p[p[x]];
                x = p[x];
            }
            x
        }
        for e in self.edges.iter().flatten() {
            let (ra, rb) = (find(&mut parent, e.a), find(&mut parent, e.b));
            parent[ra] = rb;
        }
        (0..self.nodes.len())
            .map(|n| find(&mut parent, n))
            .collect()
    }

    /// Bridges gaps: ends of one component to the nearest node of another (Kruskal, nearest
    /// first), when `distance ≤ max_gap + r_end + r_node`.
    fn bridge_gaps(&mut self, max_gap: f64) -> usize {
        let inc = self.incidence();
        let comp = self.components();
        let alive: Vec<usize> = (0..self.nodes.len())
            .filter(|&n| self.nodes[n].alive)
            .collect();
        let mut candidates = Vec::new();
        for &a in alive.iter().filter(|&&a| inc[a].len() <= 1) {
            for &b in &alive {
                if comp[a] == comp[b] {
                    continue;
                }
                let (na, nb) = (&self.nodes[a], &self.nodes[b]);
                let d = (na.pos - nb.pos).norm();
                if d <= max_gap + na.radius + nb.radius {
                    candidates.push((d, a, b));
                }
            }
        }
        candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut label: Vec<usize> = comp;
        let mut bridged = 0;
        for (_, a, b) in candidates {
            let (la, lb) = (label[a], label[b]);
            if la == lb {
                continue;
            }
            for l in &mut label {
                if *l == lb {
                    *l = la;
                }
            }
            let (na, nb) = (&self.nodes[a], &self.nodes[b]);
            self.edges.push(Some(RawEdge {
                a,
                b,
                points: vec![na.pos, nb.pos],
                radii: vec![na.radius, nb.radius],
                bridged: 1,
            }));
            bridged += 1;
        }
        bridged
    }
}

/// Graph of the skeleton voxels: nodes at voxels with ≠ 2 neighbours (adjacent branch voxels form
/// one node), edges along chains of 2-neighbour voxels.
fn raw_graph(t: &Thinned) -> RawGraph {
    let nb = t.padded.neighbour_offsets();
    let n = t.skeleton.len();
    let grid = &t.padded.grid;
    let pos = |v: usize| grid.voxel_center(grid.ijk(v));
    let neighbours = |v: usize| -> Vec<usize> {
        nb.iter()
            .map(|&d| v.wrapping_add_signed(d))
            .filter(|&w| t.skeleton[w])
            .collect()
    };
    let mut g = RawGraph::default();
    let mut node_of = vec![usize::MAX; n];
    let mut degree = vec![0usize; n];
    for v in (0..n).filter(|&v| t.skeleton[v]) {
        degree[v] = neighbours(v).len();
    }
    // Nodes: clusters of adjacent branch voxels (degree ≥ 3); single end / isolated voxels.
    for v in (0..n).filter(|&v| t.skeleton[v] && degree[v] != 2) {
        if node_of[v] != usize::MAX {
            continue;
        }
        let id = g.nodes.len();
        let mut members = vec![v];
        node_of[v] = id;
        if degree[v] >= 3 {
            let mut i = 0;
            while i < members.len() {
                for w in neighbours(members[i]) {
                    if degree[w] >= 3 && node_of[w] == usize::MAX {
                        node_of[w] = id;
                        members.push(w);
                    }
                }
                i += 1;
            }
        }
        let centre = members.iter().map(|&m| pos(m)).sum::<Vec3>() / members.len() as f64;
        let radius = members.iter().map(|&m| t.radius[m]).fold(0.0, f64::max);
        g.nodes.push(RawNode {
            pos: centre,
            radius,
            component: t.component[v],
            alive: true,
        });
    }
    let mut visited = vec![false; n];
    let mut direct = BTreeSet::new();
    let mut trace =
        |g: &mut RawGraph, node_of: &mut Vec<usize>, visited: &mut Vec<bool>, start: usize| {
            let a = node_of[start];
            for w in neighbours(start) {
                if node_of[w] != usize::MAX {
                    let b = node_of[w];
                    if b != a && direct.insert((a.min(b), a.max(b))) {
                        let (na, nb) = (&g.nodes[a], &g.nodes[b]);
                        g.edges.push(Some(RawEdge {
                            a,
                            b,
                            points: vec![na.pos, nb.pos],
                            radii: vec![na.radius, nb.radius],
                            bridged: 0,
                        }));
                    }
                    continue;
                }
                if visited[w] {
                    continue;
                }
                let mut points = vec![g.nodes[a].pos];
                let mut radii = vec![g.nodes[a].radius];
                let (mut prev, mut cur) = (start, w);
                let b = loop {
                    visited[cur] = true;
                    points.push(pos(cur));
                    radii.push(t.radius[cur]);
                    let next = neighbours(cur)
                        .into_iter()
                        .find(|&x| x != prev && !(node_of[x] == usize::MAX && visited[x]));
                    match next {
                        Some(x) if node_of[x] != usize::MAX => break node_of[x],
                        Some(x) => {
                            prev = cur;
                            cur = x;
                        }
                        None => {
                            // A chain that ends without a node (should not happen): close it here.
                            let id = g.nodes.len();
                            g.nodes.push(RawNode {
                                pos: pos(cur),
                                radius: t.radius[cur],
                                component: t.component[cur],
                                alive: true,
                            });
                            node_of[cur] = id;
                            points.pop();
                            radii.pop();
                            break id;
                        }
                    }
                };
                points.push(g.nodes[b].pos);
                radii.push(g.nodes[b].radius);
                g.edges.push(Some(RawEdge {
                    a,
                    b,
                    points,
                    radii,
                    bridged: 0,
                }));
            }
        };
    let node_voxels: Vec<usize> = (0..n).filter(|&v| node_of[v] != usize::MAX).collect();
    for v in node_voxels {
        trace(&mut g, &mut node_of, &mut visited, v);
    }
    // Cycles of 2-neighbour voxels only: a node on each.
    for v in 0..n {
        if t.skeleton[v] && degree[v] == 2 && !visited[v] && node_of[v] == usize::MAX {
            let id = g.nodes.len();
            g.nodes.push(RawNode {
                pos: pos(v),
                radius: t.radius[v],
                component: t.component[v],
                alive: true,
            });
            node_of[v] = id;
            visited[v] = true;
            trace(&mut g, &mut node_of, &mut visited, v);
        }
    }
    g
}

fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// The vessel tree of a binary mask: thinning, graph, spurs pruned, gaps bridged, oriented from
/// the root.
pub fn vessel_tree(
    mask: &Volume<bool>,
    root: RootChoice,
    params: &VesselParams,
) -> Result<VesselTree, VesselError> {
    if !(params.spur_factor.is_finite() && params.spur_factor >= 0.0) {
        return Err(VesselError::InvalidParameter {
            name: "spur_factor",
            reason: "must be finite and non-negative",
        });
    }
    if !(params.max_gap_mm.is_finite() && params.max_gap_mm >= 0.0) {
        return Err(VesselError::InvalidParameter {
            name: "max_gap_mm",
            reason: "must be finite and non-negative",
        });
    }
    if let RootChoice::NearestTo(p) = root
        && p.iter().any(|c| !c.is_finite())
    {
        return Err(VesselError::InvalidParameter {
            name: "root point",
            reason: "must be finite",
        });
    }
    let grid = mask.grid().clone();
    if !grid.is_orthogonal() {
        return Err(resecta_geom::GeomError::NonOrthogonalGrid.into());
    }
    let min_voxels = params.min_component_voxels.max(1);
    // Thinned on the mask's bounding box: the rest of the grid is background either way.
    let Some((lo, hi)) = resecta_geom::crop::bounds(mask) else {
        return Err(VesselError::EmptyVesselMask {
            specks: 0,
            min_voxels,
        });
    };
    let t = thin(&resecta_geom::crop::sub_volume(mask, lo, hi)?, min_voxels)?;
    if t.component_voxels.is_empty() {
        return Err(VesselError::EmptyVesselMask {
            specks: t.specks,
            min_voxels,
        });
    }
    let mut report = TreeReport {
        specks: t.specks,
        speck_voxels: t.speck_voxels,
        components: t.component_voxels.len(),
        skeleton_voxels: t.skeleton.iter().filter(|&&s| s).count(),
        ..TreeReport::default()
    };
    let mut g = raw_graph(&t);
    g.merge_degree_two();
    let sp = grid.spacing();
    let diag = (sp[0] * sp[0] + sp[1] * sp[1] + sp[2] * sp[2]).sqrt();
    report.spurs_pruned = g.prune_spurs(params.spur_factor, diag);
    report.gaps_bridged = g.bridge_gaps(params.max_gap_mm);
    g.merge_degree_two();
    let inc = g.incidence();
    let alive: Vec<usize> = (0..g.nodes.len()).filter(|&n| g.nodes[n].alive).collect();
    let comp = g.components();
    // The widest end of `pool` (its node of largest radius when it has no end).
    let auto_root = |pool: &[usize]| -> Option<(usize, f64)> {
        let ends: Vec<usize> = pool
            .iter()
            .copied()
            .filter(|&n| inc[n].len() == 1)
            .collect();
        let score = |n: usize| -> f64 {
            match inc[n].as_slice() {
                [e] if !ends.is_empty() => g.edges[*e]
                    .as_ref()
                    .map_or(g.nodes[n].radius, |e| median(&e.radii)),
                _ => g.nodes[n].radius,
            }
        };
        let pool = if ends.is_empty() { pool } else { &ends };
        pool.iter()
            .copied()
            .map(|n| (n, score(n)))
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
    };
    let roots: Vec<usize> = match root {
        RootChoice::Auto => auto_root(&alive).map(|r| r.0).into_iter().collect(),
        RootChoice::NearestTo(p) => alive
            .iter()
            .copied()
            .min_by(|&a, &b| {
                (g.nodes[a].pos - p)
                    .norm()
                    .total_cmp(&(g.nodes[b].pos - p).norm())
            })
            .into_iter()
            .collect(),
        RootChoice::EveryComponent => {
            let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
            for &n in &alive {
                groups.entry(comp[n]).or_default().push(n);
            }
            let mut picked: Vec<(usize, f64)> =
                groups.values().filter_map(|pool| auto_root(pool)).collect();
            picked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            picked.into_iter().map(|r| r.0).collect()
        }
    };
    let Some(&root_node) = roots.first() else {
        return Err(VesselError::EmptyVesselMask {
            specks: t.specks,
            min_voxels,
        });
    };
    let is_root = |n: usize| roots.contains(&n);
    // Shortest paths (by centreline length) from the root: the spanning tree.
    let mut dist = vec![f64::INFINITY; g.nodes.len()];
    let mut parent_edge = vec![usize::MAX; g.nodes.len()];
    let mut heap = BinaryHeap::new();
    for &r in &roots {
        dist[r] = 0.0;
        heap.push(Reverse((0u64, r)));
    }
    while let Some(Reverse((bits, u))) = heap.pop() {
        if f64::from_bits(bits) > dist[u] {
            continue;
        }
        for &e in &inc[u] {
            let Some(edge) = g.edges[e].as_ref() else {
                continue;
            };
            let v = edge.other(u);
            let d = dist[u] + edge.length();
            if d < dist[v] {
                dist[v] = d;
                parent_edge[v] = e;
                heap.push(Reverse((d.to_bits(), v)));
            }
        }
    }
    // Detached components and loops.
    let root_comps: BTreeSet<usize> = roots.iter().map(|&r| comp[r]).collect();
    let mut detached = BTreeSet::new();
    let mut detached_labels = BTreeSet::new();
    for &n in &alive {
        if !root_comps.contains(&comp[n]) {
            detached.insert(comp[n]);
            detached_labels.insert(g.nodes[n].component);
        }
    }
    let root_labels: BTreeSet<u32> = alive
        .iter()
        .filter(|&&n| root_comps.contains(&comp[n]))
        .map(|&n| g.nodes[n].component)
        .collect();
    report.detached_components = detached.len();
    report.detached_voxels = detached_labels
        .difference(&root_labels)
        .filter_map(|&l| t.component_voxels.get(l as usize))
        .sum();
    let is_tree_edge =
        |e: usize, edge: &RawEdge| parent_edge[edge.a] == e || parent_edge[edge.b] == e;
    report.loop_edges_dropped = g
        .edges
        .iter()
        .enumerate()
        .filter_map(|(i, e)| e.as_ref().map(|e| (i, e)))
        .filter(|(i, e)| root_comps.contains(&comp[e.a]) && !is_tree_edge(*i, e))
        .count();
    // Breadth-first renumbering from the root.
    let mut node_id = vec![usize::MAX; g.nodes.len()];
    let mut nodes = Vec::new();
    let mut edges: Vec<Edge> = Vec::new();
    let mut edge_of_raw = vec![usize::MAX; g.edges.len()];
    let mut push_node = |n: usize, nodes: &mut Vec<Node>| -> usize {
        if node_id[n] == usize::MAX {
            node_id[n] = nodes.len();
            nodes.push(Node {
                id: nodes.len(),
                kind: NodeKind::End,
                position: g.nodes[n].pos,
                radius: g.nodes[n].radius,
            });
        }
        node_id[n]
    };
    for &r in &roots {
        push_node(r, &mut nodes);
    }
    let mut queue: std::collections::VecDeque<usize> = roots.iter().copied().collect();
    while let Some(u) = queue.pop_front() {
        for &e in &inc[u] {
            let Some(edge) = g.edges[e].as_ref() else {
                continue;
            };
            let v = edge.other(u);
            if v == u || parent_edge[v] != e {
                continue;
            }
            let edge = if edge.a == u {
                edge.clone()
            } else {
                edge.clone().reversed()
            };
            let from = push_node(u, &mut nodes);
            let to = push_node(v, &mut nodes);
            let parent = (!is_root(u))
                .then(|| edge_of_raw.get(parent_edge[u]).copied())
                .flatten()
                .filter(|&p| p != usize::MAX);
            let id = edges.len();
            edge_of_raw[e] = id;
            let generation = parent
                .and_then(|p| edges.get(p))
                .map_or(1, |p| p.generation + 1);
            if let Some(p) = parent.and_then(|p| edges.get_mut(p)) {
                p.children.push(id);
            }
            let length_mm = edge.length();
            edges.push(Edge {
                id,
                parent,
                children: Vec::new(),
                generation,
                from,
                to,
                points: edge.points,
                radii: edge.radii,
                length_mm,
                bridged_gaps: edge.bridged,
            });
            queue.push_back(v);
        }
    }
    let mut degree = vec![0usize; nodes.len()];
    for e in &edges {
        degree[e.from] += 1;
        degree[e.to] += 1;
    }
    for n in &mut nodes {
        n.kind = if n.id < roots.len() {
            NodeKind::Root
        } else if degree[n.id] >= 2 {
            NodeKind::Branch
        } else {
            NodeKind::End
        };
    }
    debug_assert_eq!(node_id[root_node], 0);
    Ok(VesselTree {
        grid,
        root: 0,
        roots: (0..roots.len()).collect(),
        nodes,
        edges,
        report,
    })
}
