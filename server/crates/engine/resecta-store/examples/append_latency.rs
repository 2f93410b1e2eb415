#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Ack latency of log appends from concurrent sessions on the SQLite store, with and without
//! group commit, runs interleaved (off, on, off, on, …) on fresh stores in the same directory.
//!
//! ```text
//! cargo run --release -p resecta-store --example append_latency -- \
//!     [--appenders 20] [--appends 200] [--rounds 3] [--dir DIR]
//! ```
//!
//! Each appender owns one session and appends one ~300-byte edit record at a time, waiting for
//! the acknowledgement before the next (a surgeon's edit waits for its ack); latency is measured
//! around `append`. DIR (default: a temporary directory under the system's) should be on the disk
//! the server's data directory would use: the fsync is what is measured.

use std::path::PathBuf;
use std::sync::{Arc, Barrier};
use std::time::Instant;

use resecta_store::{SessionRecord, SessionStore, SqliteStore, StoreOptions};

/// A translate edit as the plan's event JSON would carry it (~300 bytes), as in benches/store.rs.
fn edit_record(seq: u64) -> String {
    format!(
        r#"{{"type":"move_points","version":{seq},"indices":[[3,4],[3,5],[4,4],[4,5]],"delta_mm":[1.25,-0.5,2.0],"client":"slicer-7f3a","at_ms":1718000000000,"margin_mm":10.0,"band_mm":5.0,"resolution":[40,40],"note":"drag group"}}"#
    )
}

struct Args {
    appenders: usize,
    appends: usize,
    rounds: usize,
    dir: Option<PathBuf>,
}

fn args() -> Args {
    let mut a = Args {
        appenders: 20,
        appends: 200,
        rounds: 3,
        dir: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_else(|| panic!("{flag} needs a value"));
        match flag.as_str() {
            "--appenders" => a.appenders = value.parse().expect("--appenders N"),
            "--appends" => a.appends = value.parse().expect("--appends N"),
            "--rounds" => a.rounds = value.parse().expect("--rounds N"),
            "--dir" => a.dir = Some(value.into()),
            other => panic!("unknown argument {other}"),
        }
    }
    a
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let k = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[k]
}

/// One run on a fresh store: every append's latency in ms, wall time, commits.
fn run(dir: &std::path::Path, group: bool, a: &Args) -> (Vec<f64>, f64, u64) {
    let store = SqliteStore::open(dir, StoreOptions::default()).unwrap();
    let store = Arc::new(if group {
        store
    } else {
        store.without_group_commit()
    });
    for s in 0..a.appenders {
        store
            .create_session(&SessionRecord {
                id: format!("s{s}"),
                display_name: "bench".into(),
                created_ms: 0,
                last_access_ms: 0,
            })
            .unwrap();
    }
    let before = store.group_commit_stats();
    let barrier = Arc::new(Barrier::new(a.appenders));
    let start = Instant::now();
    let threads: Vec<_> = (0..a.appenders)
        .map(|s| {
            let (store, barrier, n) = (store.clone(), barrier.clone(), a.appends);
            std::thread::spawn(move || {
                let id = format!("s{s}");
                let mut out = Vec::with_capacity(n);
                barrier.wait();
                for len in 0..n as u64 {
                    let t = Instant::now();
                    let new_len = store.append(&id, len, &[edit_record(len + 1)]).unwrap();
                    out.push(t.elapsed().as_secs_f64() * 1e3);
                    assert_eq!(new_len, len + 1);
                }
                out
            })
        })
        .collect();
    let mut lat: Vec<f64> = threads
        .into_iter()
        .flat_map(|t| t.join().unwrap())
        .collect();
    let wall = start.elapsed().as_secs_f64();
    lat.sort_by(f64::total_cmp);
    let commits = store.group_commit_stats().commits - before.commits;
    (lat, wall, commits)
}

fn main() {
    let a = args();
    let tmp = tempfile::tempdir_in(a.dir.clone().unwrap_or_else(std::env::temp_dir)).unwrap();
    println!(
        "# {} appenders x {} appends of ~300 B, {} rounds, dir {}",
        a.appenders,
        a.appends,
        a.rounds,
        tmp.path().display()
    );
    println!(
        "round mode          p50_ms  p90_ms  p99_ms  max_ms  appends/s  commits  appends/commit"
    );
    for round in 1..=a.rounds {
        for group in [false, true] {
            let dir = tmp.path().join(format!("r{round}-{group}"));
            let (lat, wall, commits) = run(&dir, group, &a);
            let n = lat.len();
            println!(
                "{round:5} {:<14} {:7.2} {:7.2} {:7.2} {:7.2} {:10.0} {:8} {:15.2}",
                if group {
                    "group-commit"
                } else {
                    "one-per-append"
                },
                percentile(&lat, 50.0),
                percentile(&lat, 90.0),
                percentile(&lat, 99.0),
                lat[n - 1],
                n as f64 / wall,
                commits,
                n as f64 / commits.max(1) as f64,
            );
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }
}
