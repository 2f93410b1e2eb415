//! Label roles: which label values of a label map are parenchyma, tumour, vessels.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::error::GeomError;

/// The anatomical role of a label value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Liver tissue that is neither tumour nor vessel.
    Parenchyma,
    Tumor,
    /// Portal vein tree.
    Portal,
    /// Hepatic vein tree.
    Hepatic,
    /// A vessel label that is not split into portal and hepatic (e.g. MSD Task08).
    Vessel,
}

impl Role {
    pub const ALL: [Role; 5] = [
        Role::Parenchyma,
        Role::Tumor,
        Role::Portal,
        Role::Hepatic,
        Role::Vessel,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Role::Parenchyma => "parenchyma",
            Role::Tumor => "tumor",
            Role::Portal => "portal",
            Role::Hepatic => "hepatic",
            Role::Vessel => "vessel",
        }
    }

    /// Whether voxels of this role count as functional liver in volumetry (tumours do not).
    pub fn is_functional_liver(self) -> bool {
        !matches!(self, Role::Tumor)
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Role → label values, e.g. `{"parenchyma":[1],"tumor":[2],"portal":[3],"hepatic":[4]}`.
///
/// Validated: no label 0, no label in two roles, no role without labels.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(
    try_from = "BTreeMap<Role, Vec<u16>>",
    into = "BTreeMap<Role, Vec<u16>>"
)]
pub struct RoleMap {
    roles: BTreeMap<Role, Vec<u16>>,
}

impl Default for RoleMap {
    /// `{"parenchyma":[1],"tumor":[2],"portal":[3],"hepatic":[4]}`.
    fn default() -> Self {
        let roles = [
            (Role::Parenchyma, 1),
            (Role::Tumor, 2),
            (Role::Portal, 3),
            (Role::Hepatic, 4),
        ]
        .into_iter()
        .map(|(r, l)| (r, vec![l]))
        .collect();
        Self { roles }
    }
}

impl TryFrom<BTreeMap<Role, Vec<u16>>> for RoleMap {
    type Error = GeomError;

    fn try_from(mut roles: BTreeMap<Role, Vec<u16>>) -> Result<Self, GeomError> {
        let mut owner: BTreeMap<u16, Role> = BTreeMap::new();
        for (&role, labels) in roles.iter_mut() {
            if labels.is_empty() {
                return Err(GeomError::EmptyRole(role.to_string()));
            }
            labels.sort_unstable();
            labels.dedup();
            for &l in labels.iter() {
                if l == 0 {
                    return Err(GeomError::BackgroundLabel);
                }
                if let Some(first) = owner.insert(l, role) {
                    return Err(GeomError::LabelInTwoRoles {
                        label: l,
                        first: first.to_string(),
                        second: role.to_string(),
                    });
                }
            }
        }
        Ok(Self { roles })
    }
}

impl From<RoleMap> for BTreeMap<Role, Vec<u16>> {
    fn from(m: RoleMap) -> Self {
        m.roles
    }
}

impl RoleMap {
    /// Labels of `role` (empty if the role is absent).
    pub fn labels(&self, role: Role) -> &[u16] {
        self.roles.get(&role).map_or(&[], Vec::as_slice)
    }

    /// The role of a label value, if any.
    pub fn role_of(&self, label: u16) -> Option<Role> {
        self.roles
            .iter()
            .find(|(_, ls)| ls.contains(&label))
            .map(|(&r, _)| r)
    }

    /// Roles present, in order.
    pub fn roles(&self) -> impl Iterator<Item = (Role, &[u16])> {
        self.roles.iter().map(|(&r, ls)| (r, ls.as_slice()))
    }

    /// A 65 536-entry table label → role, for per-voxel loops.
    pub fn lookup_table(&self) -> Vec<Option<Role>> {
        let mut t = vec![None; 1 << 16];
        for (&r, ls) in &self.roles {
            for &l in ls {
                t[usize::from(l)] = Some(r);
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_contract_example() {
        let m: RoleMap =
            serde_json::from_str(r#"{"parenchyma":[1],"tumor":[2],"portal":[3],"hepatic":[4]}"#)
                .unwrap();
        assert_eq!(m, RoleMap::default());
        assert_eq!(m.role_of(3), Some(Role::Portal));
        assert_eq!(m.role_of(9), None);
        assert_eq!(m.lookup_table()[2], Some(Role::Tumor));
        let back = serde_json::to_string(&m).unwrap();
        assert_eq!(
            back,
            r#"{"parenchyma":[1],"tumor":[2],"portal":[3],"hepatic":[4]}"#
        );
    }

    #[test]
    fn refuses_bad_maps() {
        let e = serde_json::from_str::<RoleMap>(r#"{"parenchyma":[1,2],"tumor":[2]}"#).unwrap_err();
        assert!(e.to_string().contains("label 2"), "{e}");
        assert!(serde_json::from_str::<RoleMap>(r#"{"parenchyma":[0]}"#).is_err());
        assert!(serde_json::from_str::<RoleMap>(r#"{"tumor":[]}"#).is_err());
        assert!(serde_json::from_str::<RoleMap>(r#"{"spleen":[5]}"#).is_err());
        assert!(serde_json::from_str::<RoleMap>(r#"{"tumor":[70000]}"#).is_err());
    }
}
