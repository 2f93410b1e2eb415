//! Plan files and persisted edit logs on arbitrary bytes: `Ok` or a typed error, never a
//! panic; an accepted plan round-trips through its own JSON.
#![no_main]

use libfuzzer_sys::fuzz_target;
use resecta_plan::{History, LogEntry, Plan, PlanEvent};

/// A log in the seeds' shape: `[{"kind":"edit","event":{…}}, {"kind":"undo"}, …]`.
fn log(text: &str) -> Option<Vec<LogEntry>> {
    let entries: Vec<serde_json::Value> = serde_json::from_str(text).ok()?;
    entries
        .into_iter()
        .map(|e| match e.get("kind")?.as_str()? {
            "edit" => Some(LogEntry::Edit {
                event: serde_json::from_value::<PlanEvent>(e.get("event")?.clone()).ok()?,
            }),
            "undo" => Some(LogEntry::Undo),
            "redo" => Some(LogEntry::Redo),
            _ => None,
        })
        .collect()
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    // A plan, optionally followed by a log after a form feed.
    let (plan_text, log_text) = text.split_once('\u{c}').unwrap_or((text, "[]"));
    if let Ok(plan) = Plan::from_json(plan_text) {
        let again = Plan::from_json(&plan.to_json().expect("serialises")).expect("round-trips");
        assert_eq!(again, plan);
        if let Some(log) = log(log_text) {
            let _ = History::replay(plan, &log);
        }
    }
});
