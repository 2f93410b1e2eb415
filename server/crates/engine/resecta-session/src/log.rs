//! The session log: how a session is kept in the store (log records, blobs) and how it comes
//! back from there (replay), and the rollback of an edit whose record could not be stored. The
//! only code that knows the storage format.

use std::sync::Arc;

use resecta_delta::{DecodeLimits, SurfaceFrame, Topology, decode_mesh};
use resecta_geom::{LabelMap, Real, RoleMap, TriMesh, Vec3};
use resecta_plan::{History, LogEntry, Plan, Planner};
use resecta_store::{Blob, LogRecord, SessionRecord, SessionStore};

use crate::api::{LabelMapSummary, ModelInfo, Surface};
use crate::error::{Result, SessionError};
use crate::labelmap;
use crate::record::{self, ModelRecord, Step, SummaryRecord};
use crate::state::Model;
use crate::support::internal;

pub(crate) const LABELMAP_BLOB: &str = "labelmap";
pub(crate) const SUMMARY_BLOB: &str = "summary";
pub(crate) const MODELS_BLOB: &str = "models";

/// The log record that starts a new base plan.
pub(crate) fn reset_record(plan: &Plan) -> Result<String> {
    // Compact: the largest plan the plan limits allow fits the store's record limit.
    let json = serde_json::to_string(plan).map_err(internal)?;
    record::encode_reset(json)
}

/// The log record of one edit.
pub(crate) fn entry_record(entry: &LogEntry) -> Result<String> {
    record::encode_entry(entry)
}

/// The base plan and the edits that follow it in `records` (a reset drops what came before);
/// `roles` gives the base while no reset is stored.
pub(crate) fn base_and_entries<'a>(
    records: impl IntoIterator<Item = &'a str>,
    roles: &RoleMap,
) -> Result<(Plan, Vec<LogEntry>)> {
    let mut base = Plan::new(roles.clone());
    let mut entries = Vec::new();
    for r in records {
        match record::decode(r)? {
            Step::Reset(plan) => {
                base = Plan::from_json(&plan)?;
                entries.clear();
            }
            Step::Entry(entry) => entries.push(entry),
        }
    }
    Ok((base, entries))
}

/// A session as stored, read but not yet decoded.
pub(crate) struct Stored {
    rec: SessionRecord,
    version: u64,
    labels: Option<(Blob, Vec<LogRecord>)>,
    models: Option<Blob>,
}

/// Reads the session `id` (store I/O: run it on the blocking pool).
pub(crate) fn load(store: &dyn SessionStore, id: &str) -> Result<Stored> {
    let Some(rec) = store.session(id)? else {
        return Err(SessionError::UnknownSession(id.into()));
    };
    let version = store.log_len(id)?;
    let labels = match store.blob(id, LABELMAP_BLOB)? {
        None => None,
        Some(blob) => Some((blob, store.log(id, 0)?)),
    };
    let models = store.blob(id, MODELS_BLOB)?;
    Ok(Stored {
        rec,
        version,
        labels,
        models,
    })
}

/// A session decoded and its log replayed: the plan history its planner resumes once the
/// anatomy is set up.
pub(crate) struct Restored {
    pub(crate) rec: SessionRecord,
    pub(crate) version: u64,
    pub(crate) loaded: Option<(Arc<LabelMap>, LabelMapSummary, RoleMap, History)>,
    pub(crate) models: Option<Vec<Model>>,
}

/// Decodes a stored session and replays its log to its plan (CPU work: a worker pool).
pub(crate) fn rebuild(stored: Stored, max_voxels: u64) -> Result<Restored> {
    let Stored {
        rec,
        version,
        labels,
        models,
    } = stored;
    let loaded = match labels {
        None => None,
        Some((blob, records)) => {
            let (labels, roles) = labelmap::from_blob(&blob, max_voxels)?;
            let (base, entries) =
                base_and_entries(records.iter().map(|r| r.json.as_str()), &roles)?;
            let history = History::replay(base, &entries)?;
            let summary = labelmap::summary(&labels, &roles);
            Some((Arc::new(labels), summary, roles, history))
        }
    };
    let models = models.map(|b| decode_models(&b)).transpose()?;
    Ok(Restored {
        rec,
        version,
        loaded,
        models,
    })
}

/// Stores a new label map with its summary, drops the models and appends the reset to an empty
/// plan on `roles` after `version` records; returns that plan and the new version (store I/O).
pub(crate) fn store_label_map(
    store: &dyn SessionStore,
    key: &str,
    version: u64,
    labels: &LabelMap,
    roles: &RoleMap,
    summary: &LabelMapSummary,
) -> Result<(Plan, u64)> {
    let plan = Plan::new(roles.clone());
    let summary_blob = Blob {
        meta_json: serde_json::to_string(&SummaryRecord::from(summary)).map_err(internal)?,
        data: Vec::new(),
    };
    store.put_blob(key, LABELMAP_BLOB, &labelmap::to_blob(labels, roles)?)?;
    store.put_blob(key, SUMMARY_BLOB, &summary_blob)?;
    store.delete_blob(key, MODELS_BLOB)?;
    let record = reset_record(&plan)?;
    let version = store.append(key, version, &[record])?;
    Ok((plan, version))
}

/// What describes a session not loaded in memory: its plan version, label-map summary and
/// whether it has models (store I/O).
pub(crate) fn stored_summary(
    store: &dyn SessionStore,
    key: &str,
) -> Result<(u64, Option<LabelMapSummary>, bool)> {
    let version = store.log_len(key)?;
    let summary = store.blob(key, SUMMARY_BLOB)?;
    let models = store.blob(key, MODELS_BLOB)?.is_some();
    let summary: Option<LabelMapSummary> = summary
        .map(|b| serde_json::from_str::<SummaryRecord>(&b.meta_json).map(Into::into))
        .transpose()
        .map_err(internal)?;
    Ok((version, summary, models))
}

/// Stores the models (store I/O).
pub(crate) fn store_models(store: &dyn SessionStore, key: &str, blob: &Blob) -> Result<()> {
    Ok(store.put_blob(key, MODELS_BLOB, blob)?)
}

/// Rebuilds the planner without its last log entry (whose record could not be stored).
pub(crate) fn roll_back(planner: &mut Planner, id: &str) {
    let h = planner.history();
    let log = h.log();
    let restored =
        History::replay(h.base().clone(), &log[..log.len().saturating_sub(1)]).and_then(|h| {
            let engine = planner.compute_engine().clone();
            Planner::resume_with_engine(planner.anatomy_shared(), h, engine)
        });
    match restored {
        Ok(p) => *planner = p,
        Err(r) => {
            tracing::error!(session = %id, error = %SessionError::Plan(r), "rollback after a storage failure failed")
        }
    }
}

/// Models as a blob: JSON infos with byte lengths, then the `RSMS` encodings back to back.
pub(crate) fn encode_models(models: &[Model]) -> Result<Blob> {
    let meta: Vec<(ModelRecord, usize)> = models
        .iter()
        .map(|m| (ModelRecord::from(&m.info), m.surface.mesh.len()))
        .collect();
    Ok(Blob {
        meta_json: serde_json::to_string(&meta).map_err(internal)?,
        data: models
            .iter()
            .flat_map(|m| m.surface.mesh.iter().copied())
            .collect(),
    })
}

pub(crate) fn decode_models(blob: &Blob) -> Result<Vec<Model>> {
    let meta: Vec<(ModelRecord, usize)> =
        serde_json::from_str(&blob.meta_json).map_err(internal)?;
    let mut at = 0usize;
    let mut out = Vec::with_capacity(meta.len());
    for (info, len) in meta {
        let info = ModelInfo::from(info);
        let bytes = at
            .checked_add(len)
            .and_then(|end| blob.data.get(at..end))
            .ok_or_else(|| internal("stored models are truncated"))?;
        at += len;
        let (topology, frame): (Topology, SurfaceFrame) =
            decode_mesh(bytes, &DecodeLimits::default()).map_err(internal)?;
        let vertices = frame
            .positions
            .iter()
            .map(|p| Vec3::new(Real::from(p[0]), Real::from(p[1]), Real::from(p[2])))
            .collect();
        let mesh = TriMesh::new(vertices, topology.triangles).map_err(internal)?;
        out.push(Model {
            surface: Surface::labelled(info.name.clone(), info.kind, info.label, bytes.to_vec()),
            info,
            mesh,
        });
    }
    Ok(out)
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reset_drops_what_came_before() {
        let roles = RoleMap::default();
        let plan = Plan::new(roles.clone());
        let reset = reset_record(&plan).unwrap();
        let (base, entries) = base_and_entries([reset.as_str(), reset.as_str()], &roles).unwrap();
        assert_eq!(base.to_json().unwrap(), plan.to_json().unwrap());
        assert!(entries.is_empty());
    }

    /// The plan limits and the store's record limit agree: the record of the largest plan the
    /// limits allow (every count at its maximum, names of the longest UTF-8, coordinates of the
    /// longest text) is stored by a store with default options.
    #[test]
    fn the_largest_plan_fits_a_log_record() {
        use resecta_bezier::MAX_CONTROL_POINTS as M;
        use resecta_plan::resection::{
            MAX_NAME_LEN, MAX_RESOLUTION, MAX_TARGET_LABELS, MAX_TARGET_POINTS,
        };
        let longest = [
            -12345.678901234567,
            -2.2250738585072014e-308,
            -99999.99999999999,
        ];
        let tumours: Vec<u16> = (u16::MAX - MAX_TARGET_LABELS as u16 + 1..=u16::MAX).collect();
        let resections: Vec<_> = (0..resecta_plan::MAX_RESECTIONS)
            .map(|k| {
                let name = format!("{k:02}{}", "\u{10348}".repeat((MAX_NAME_LEN - 2) / 4));
                serde_json::json!({
                    "name": name, "grid": [M, M], "control_points": vec![longest; M * M],
                    "margin_mm": 9.999999999999998, "band_mm": 9.999999999999998,
                    "resolution": [MAX_RESOLUTION, MAX_RESOLUTION],
                    "target": {
                        "labels": tumours,
                        "points": vec![longest; MAX_TARGET_POINTS],
                    },
                })
            })
            .collect();
        let json = serde_json::json!({
            "format": resecta_plan::FORMAT,
            "roles": {"parenchyma": [1], "tumor": tumours},
            "resections": resections,
        });
        let plan = Plan::from_json(&json.to_string()).unwrap();
        let record = reset_record(&plan).unwrap();
        let limit = resecta_store::StoreOptions::default().max_record_bytes;
        assert!(
            record.len() > 8 << 20,
            "{} bytes: not the largest",
            record.len()
        );
        assert!(record.len() <= limit, "{} > {limit}", record.len());
        let store = resecta_store::MemoryStore::new(resecta_store::StoreOptions::default());
        let rec = SessionRecord {
            id: "s".into(),
            display_name: "d".into(),
            created_ms: 0,
            last_access_ms: 0,
        };
        store.create_session(&rec).unwrap();
        store.append("s", 0, &[record]).unwrap();
    }

    #[test]
    fn a_log_written_by_version_1_replays() {
        let records = include_str!("../tests/fixtures/log-v1.jsonl");
        let want = Plan::from_json(include_str!("../tests/fixtures/log-v1.plan.json")).unwrap();
        let (base, entries) = base_and_entries(records.lines(), &RoleMap::default()).unwrap();
        assert_eq!(entries.len(), 17);
        let history = History::replay(base, &entries).unwrap();
        assert_eq!(history.plan(), &want);
        // Written again in the current version, the same log replays to the same plan.
        let mut again = vec![reset_record(history.base()).unwrap()];
        again.extend(history.log().iter().map(|e| entry_record(e).unwrap()));
        assert!(again.iter().all(|r| r.starts_with(r#"{"v":2,"#)));
        let (base, entries) =
            base_and_entries(again.iter().map(String::as_str), &RoleMap::default()).unwrap();
        assert_eq!(History::replay(base, &entries).unwrap().plan(), &want);
    }

    #[test]
    fn a_record_of_a_newer_version_is_refused_by_name() {
        let r = base_and_entries([r#"{"v":3,"kind":"undo"}"#], &RoleMap::default());
        assert!(matches!(r, Err(SessionError::Internal(m)) if m.contains("version 3")));
    }

    #[test]
    fn an_unknown_record_is_an_error() {
        let roles = RoleMap::default();
        let r = base_and_entries([r#"{"type":"nonsense"}"#], &roles);
        assert!(matches!(r, Err(SessionError::Internal(_))));
    }

    #[test]
    fn models_round_trip_and_truncation_is_detected() {
        assert!(
            decode_models(&encode_models(&[]).unwrap())
                .unwrap()
                .is_empty()
        );
        let truncated = Blob {
            meta_json: r#"[[{"name":"liver","kind":"parenchyma","label":1,"method":"psr","triangles":1,"vertices":3,"volume_ml":0.0},10]]"#.into(),
            data: vec![0; 4],
        };
        assert!(matches!(
            decode_models(&truncated),
            Err(SessionError::Internal(m)) if m.contains("truncated")
        ));
    }
}
