//! Edit history: an append-only log of edits, undos and redos (what a server persists), and the
//! plan it produces. Undo and redo reach any depth; replaying the log rebuilds the same plan.

use serde::{Deserialize, Serialize};

use crate::error::PlanError;
use crate::plan::{Plan, PlanEvent};

/// Most log entries one history holds (a long drag session is a few thousand).
pub const MAX_LOG: usize = 1_000_000;
/// A snapshot of the plan is kept every this many applied events, so undo replays at most this many.
const CHECKPOINT_EVERY: usize = 64;

/// One entry of the persisted log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LogEntry {
    Edit { event: PlanEvent },
    Undo,
    Redo,
}

/// The plan, its undoable edits and the log.
#[derive(Debug, Clone)]
pub struct History {
    base: Plan,
    log: Vec<LogEntry>,
    /// The current branch of edits; `applied` of them are in effect.
    events: Vec<PlanEvent>,
    applied: usize,
    /// `checkpoints[k]` = plan after `k·CHECKPOINT_EVERY` events.
    checkpoints: Vec<Plan>,
    current: Plan,
}

impl History {
    /// A history starting at `base` (e.g. a loaded plan file).
    pub fn new(base: Plan) -> Self {
        Self {
            checkpoints: vec![base.clone()],
            current: base.clone(),
            base,
            log: Vec::new(),
            events: Vec::new(),
            applied: 0,
        }
    }

    /// Rebuilds a history by replaying its log from `base`.
    pub fn replay(base: Plan, log: &[LogEntry]) -> Result<Self, PlanError> {
        let mut h = Self::new(base);
        for (k, entry) in log.iter().enumerate() {
            let r = match entry {
                LogEntry::Edit { event } => h.edit(event.clone()),
                LogEntry::Undo => h.undo(),
                LogEntry::Redo => h.redo(),
            };
            r.map_err(|e| PlanError::InvalidArgument(format!("log entry {k}: {e}")))?;
        }
        Ok(h)
    }

    /// The plan now.
    pub fn plan(&self) -> &Plan {
        &self.current
    }
    /// The plan the history started from.
    pub fn base(&self) -> &Plan {
        &self.base
    }
    /// Every entry so far, in order (what a store appends).
    pub fn log(&self) -> &[LogEntry] {
        &self.log
    }
    /// Edits that `undo` can take back.
    pub fn undo_depth(&self) -> usize {
        self.applied
    }
    /// Edits that `redo` can restore.
    pub fn redo_depth(&self) -> usize {
        self.events.len() - self.applied
    }

    fn push_log(&mut self, entry: LogEntry) -> Result<(), PlanError> {
        if self.log.len() >= MAX_LOG {
            return Err(PlanError::HistoryFull(self.log.len() + 1));
        }
        self.log.push(entry);
        Ok(())
    }

    /// Applies an edit; drops the redo branch. On error nothing changes.
    pub fn edit(&mut self, event: PlanEvent) -> Result<&Plan, PlanError> {
        if self.log.len() >= MAX_LOG {
            return Err(PlanError::HistoryFull(self.log.len() + 1));
        }
        let mut next = self.current.clone();
        next.apply(&event)?;
        self.events.truncate(self.applied);
        self.checkpoints
            .truncate(self.applied / CHECKPOINT_EVERY + 1);
        self.events.push(event.clone());
        self.applied += 1;
        if self.applied.is_multiple_of(CHECKPOINT_EVERY) {
            self.checkpoints.push(next.clone());
        }
        self.current = next;
        self.push_log(LogEntry::Edit { event })?;
        Ok(&self.current)
    }

    /// The plan an [`Self::undo`] would give, without changing anything.
    pub fn undo_preview(&self) -> Result<Plan, PlanError> {
        if self.applied == 0 {
            return Err(PlanError::NothingToUndo);
        }
        self.state(self.applied - 1)
    }

    /// The plan a [`Self::redo`] would give, without changing anything.
    pub fn redo_preview(&self) -> Result<Plan, PlanError> {
        let event = self
            .events
            .get(self.applied)
            .ok_or(PlanError::NothingToRedo)?;
        let mut next = self.current.clone();
        next.apply(event)?;
        Ok(next)
    }

    /// Takes back the last edit in effect.
    pub fn undo(&mut self) -> Result<&Plan, PlanError> {
        if self.applied == 0 {
            return Err(PlanError::NothingToUndo);
        }
        let plan = self.state(self.applied - 1)?;
        self.push_log(LogEntry::Undo)?;
        self.applied -= 1;
        self.current = plan;
        Ok(&self.current)
    }

    /// Restores the last undone edit.
    pub fn redo(&mut self) -> Result<&Plan, PlanError> {
        let Some(event) = self.events.get(self.applied) else {
            return Err(PlanError::NothingToRedo);
        };
        let mut next = self.current.clone();
        next.apply(event)?;
        self.push_log(LogEntry::Redo)?;
        self.applied += 1;
        self.current = next;
        Ok(&self.current)
    }

    /// The plan after the first `k` events of the current branch.
    fn state(&self, k: usize) -> Result<Plan, PlanError> {
        let c = (k / CHECKPOINT_EVERY).min(self.checkpoints.len() - 1);
        let mut plan = self.checkpoints[c].clone();
        for e in &self.events[c * CHECKPOINT_EVERY..k] {
            plan.apply(e)?;
        }
        Ok(plan)
    }
}
