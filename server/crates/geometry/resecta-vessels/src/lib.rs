//! Vessel trees from label masks and the vascular territories they feed or drain.
//!
//! Pure and synchronous (geometry layer). Three steps:
//!
//! 1. **Skeleton** ([`vessel_tree`] calls it): the mask is split into 26-connected components;
//!    components of fewer than [`VesselParams::min_component_voxels`] voxels are specks, dropped
//!    and counted in [`TreeReport`]. Each voxel's radius is its exact anisotropic EDT value:
//!    the distance in mm from its centre to the nearest background voxel centre
//!    (`resecta_geom::distance_transform`). The mask is then thinned by our own
//!    **distance-ordered, directional, sequential simple-point thinning**: six sub-iterations per
//!    round (border voxels whose −i, +i, −j, +j, −k, +k neighbour is background), candidates of a
//!    sub-iteration visited by increasing radius, each deleted when it is *simple* for (26, 6)
//!    topology (one 26-component of object in its 26-neighbourhood, one 6-component of
//!    background in its 18-neighbourhood meeting its 6 faces) and not an *end point* (at most
//!    one object neighbour). Rounds repeat until nothing changes, then undirected passes remove
//!    the last simple non-end voxels, leaving curves one voxel thick. Topology is preserved
//!    (every deletion is of a simple point), and peeling from all six sides in turn keeps the
//!    curves medial. The mask is padded with one background voxel, so masks touching the grid
//!    edge are thinned as if the outside were background. Sheared grids are refused (the EDT is
//!    exact on orthogonal grids, oblique ones included).
//! 2. **Graph** ([`vessel_tree`]): skeleton voxels with ≠ 2 neighbours are nodes (adjacent
//!    branch voxels merge into one node at their centroid, with their largest radius), chains of
//!    2-neighbour voxels are edges (polylines of voxel centres in RAS mm with the radius at each
//!    point). Spurs — terminal edges at a branch point shorter than
//!    `spur_factor · r_branch + voxel diagonal` — are pruned (surface roughness and flat caps
//!    make them). Gaps between fragments are bridged: an end of one graph component is joined by
//!    a straight segment to the nearest node of another when their distance is at most
//!    `max_gap_mm + r_end + r_node` (a tube's skeleton stops about one radius before a cut end),
//!    nearest pairs first (Kruskal); bridged gaps are counted per edge and in the report.
//!    Nodes of degree 2 are then merged away. The **root** is, by [`RootChoice::Auto`], the end
//!    point whose terminal edge has the largest median radius (the trunk at the hilum or the
//!    ostium at the vena cava is the widest end; ties go to the lower node), or the node nearest
//!    a given point ([`RootChoice::NearestTo`]). The tree is the shortest-path tree (centreline
//!    length) from the root: edges are numbered breadth-first (parents before children), oriented
//!    away from the root, each with its parent, children and **generation** (1 for the edges
//!    leaving the root, parent + 1 below). Graph components not reached from the root are left
//!    out and reported (count and mask voxels); edges closing a cycle are left out and counted.
//! 3. **Territories** ([`territories`]): a branch is a selected edge with all its descendants
//!    ([`BranchSelection::Ids`], or [`BranchSelection::Generation`]: every edge of generation
//!    `k` plus the terminal edges of lower generations). Centrelines are resampled every
//!    `sample_mm` (default half the smallest spacing) and rasterised to their nearest voxels;
//!    branch points are left out (so no child is favoured there), the root and the distal ends
//!    are kept. Each liver voxel takes the territory of its nearest rasterised centreline voxel
//!    (`resecta_geom::distance_transform_with_nearest`: the exact Euclidean Voronoi diagram of
//!    those voxels, in mm on the anisotropic grid). Centrelines above every selected branch
//!    (e.g. the trunk) form the **proximal** territory, reported first, so the territories
//!    partition the liver mask exactly. See `docs/vessels.md` for the measured accuracy.
//! 4. **Risk** ([`RiskModel`]): the vessels a resection cuts (centreline crossings with its
//!    surface inside the liver), the trees beyond each cut disconnected, and the remnant whose
//!    nearest portal point is disconnected (devascularised) or whose nearest hepatic point is
//!    (congested); the functional remnant is the rest.

mod error;
mod graph;
mod risk;
mod skeleton;
mod territory;

pub use error::VesselError;
pub use graph::{
    Edge, Node, NodeKind, RootChoice, TreeReport, VesselParams, VesselTree, vessel_tree,
};
pub use risk::{Crossing, CutBranch, RiskAssessment, RiskModel, RiskRegions, VesselSystem};
pub use territory::{BranchSelection, Territories, Territory, TerritoryParams, territories};
