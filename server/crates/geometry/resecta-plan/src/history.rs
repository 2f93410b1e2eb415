//! Edit history: an append-only log of edits, undos and redos (what a server persists), and the
//! plan it produces. Undo and redo reach any depth; replaying the log rebuilds the same plan.

use crate::error::PlanError;
use crate::plan::{Plan, PlanEvent};

/// Most log entries one history holds (a long drag session is a few thousand).
pub const MAX_LOG: usize = 1_000_000;
/// A snapshot of the plan is kept every this many applied events, so undo replays at most this many.
const CHECKPOINT_EVERY: usize = 64;

/// One entry of the log (a server stores it in its own record format).
#[derive(Debug, Clone, PartialEq)]
pub enum LogEntry {
    Edit { event: PlanEvent },
    Undo,
    Redo,
}

/// What a recorded step changed: the resections whose state must be recomputed or dropped, and
/// the entry it added to the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    /// Resections the step added or changed.
    pub changed: Vec<String>,
    /// Resections the step deleted.
    pub removed: Vec<String>,
    /// The entry logged (what a store appends).
    pub entry: LogEntry,
}

/// A step (edit, undo or redo) computed against a history but not yet recorded: the plan it
/// leads to and what it changes. [`History::record`] takes it as it is, without applying
/// anything again.
#[derive(Debug)]
pub struct Staged {
    next: Plan,
    entry: LogEntry,
    changed: Vec<String>,
    removed: Vec<String>,
    /// The history's log length when staged.
    at: usize,
}

impl Staged {
    /// The plan after the step.
    pub fn plan(&self) -> &Plan {
        &self.next
    }
    /// Resections the step adds or changes.
    pub fn changed(&self) -> &[String] {
        &self.changed
    }
    /// Resections the step deletes.
    pub fn removed(&self) -> &[String] {
        &self.removed
    }
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

    fn check_room(&self) -> Result<(), PlanError> {
        if self.log.len() >= MAX_LOG {
            return Err(PlanError::HistoryFull(self.log.len() + 1));
        }
        Ok(())
    }

    /// Computes an edit (its event applied once, to a copy of the plan) without recording it;
    /// [`Self::record`] records it. On error nothing changes.
    pub fn stage_edit(&self, event: PlanEvent) -> Result<Staged, PlanError> {
        self.check_room()?;
        let mut next = self.current.clone();
        next.apply(&event)?;
        let (changed, removed) = difference(&self.current, &next, event.resection_name());
        Ok(self.staged(next, changed, removed, LogEntry::Edit { event }))
    }

    /// Computes an undo without recording it (the plan one edit back, from the nearest
    /// checkpoint).
    pub fn stage_undo(&self) -> Result<Staged, PlanError> {
        let Some(last) = self.applied.checked_sub(1) else {
            return Err(PlanError::NothingToUndo);
        };
        self.check_room()?;
        let next = self.state(last)?;
        let (changed, removed) =
            difference(&self.current, &next, self.events[last].resection_name());
        Ok(self.staged(next, changed, removed, LogEntry::Undo))
    }

    /// Computes a redo without recording it.
    pub fn stage_redo(&self) -> Result<Staged, PlanError> {
        let event = self
            .events
            .get(self.applied)
            .ok_or(PlanError::NothingToRedo)?;
        self.check_room()?;
        let mut next = self.current.clone();
        next.apply(event)?;
        let (changed, removed) = difference(&self.current, &next, event.resection_name());
        Ok(self.staged(next, changed, removed, LogEntry::Redo))
    }

    fn staged(
        &self,
        next: Plan,
        changed: Vec<String>,
        removed: Vec<String>,
        entry: LogEntry,
    ) -> Staged {
        Staged {
            next,
            entry,
            changed,
            removed,
            at: self.log.len(),
        }
    }

    /// Records a step staged on this history as it still is: the plan it computed becomes the
    /// current one, and its entry is logged. A step staged before another was recorded is
    /// refused (nothing changes).
    pub fn record(&mut self, step: Staged) -> Result<Change, PlanError> {
        if step.at != self.log.len() {
            return Err(PlanError::InvalidArgument(format!(
                "a step staged at log entry {} cannot be recorded at entry {}",
                step.at,
                self.log.len()
            )));
        }
        self.check_room()?;
        let Staged {
            next,
            entry,
            changed,
            removed,
            ..
        } = step;
        match &entry {
            LogEntry::Edit { event } => {
                self.events.truncate(self.applied);
                self.checkpoints
                    .truncate(self.applied / CHECKPOINT_EVERY + 1);
                self.events.push(event.clone());
                self.applied += 1;
                if self.applied.is_multiple_of(CHECKPOINT_EVERY) {
                    self.checkpoints.push(next.clone());
                }
            }
            LogEntry::Undo => self.applied -= 1,
            LogEntry::Redo => self.applied += 1,
        }
        self.current = next;
        self.log.push(entry.clone());
        Ok(Change {
            changed,
            removed,
            entry,
        })
    }

    /// Applies an edit (stage and record); drops the redo branch. On error nothing changes.
    pub fn edit(&mut self, event: PlanEvent) -> Result<&Plan, PlanError> {
        let step = self.stage_edit(event)?;
        self.record(step)?;
        Ok(&self.current)
    }

    /// Takes back the last edit in effect.
    pub fn undo(&mut self) -> Result<&Plan, PlanError> {
        let step = self.stage_undo()?;
        self.record(step)?;
        Ok(&self.current)
    }

    /// Restores the last undone edit.
    pub fn redo(&mut self) -> Result<&Plan, PlanError> {
        let step = self.stage_redo()?;
        self.record(step)?;
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

/// The resections changed and removed from `before` to `after`, where the step between them is
/// an event about resection `name`, its undo or its redo: every event changes that resection
/// only, so only it is compared.
fn difference(before: &Plan, after: &Plan, name: &str) -> (Vec<String>, Vec<String>) {
    let (mut changed, mut removed) = (Vec::new(), Vec::new());
    let was = before.resection(name).ok();
    if let Ok(now) = after.resection(name) {
        if was != Some(now) {
            changed.push(name.to_owned());
        }
    } else if was.is_some() {
        removed.push(name.to_owned());
    }
    (changed, removed)
}
