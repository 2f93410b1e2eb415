//! Errors of vessel trees and territories.

use resecta_geom::GeomError;

/// What can be wrong with the input of [`crate::vessel_tree`] or [`crate::territories`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VesselError {
    /// The grid or a distance transform refused the input (e.g. a sheared grid).
    #[error(transparent)]
    Geom(#[from] GeomError),
    /// No vessel voxel is left once specks are dropped.
    #[error(
        "vessel mask is empty after dropping {specks} speck(s) of fewer than {min_voxels} voxels"
    )]
    EmptyVesselMask { specks: usize, min_voxels: usize },
    /// The liver mask has no voxel.
    #[error("liver mask is empty")]
    EmptyLiver,
    /// The liver mask lies on another grid than the vessel tree.
    #[error("liver mask grid differs from the vessel tree's grid")]
    GridMismatch,
    /// A branch id that the tree does not have.
    #[error("branch {id} does not exist (the tree has {count} branches)")]
    UnknownBranch { id: usize, count: usize },
    /// The selection names no branch.
    #[error("no branch selected")]
    NoBranchSelected,
    /// The selected branches have no centreline point on the grid.
    #[error("the vessel tree has no centreline point to build territories from")]
    NoCentreline,
    /// A parameter out of its range.
    #[error("{name} {reason}")]
    InvalidParameter {
        name: &'static str,
        reason: &'static str,
    },
}
