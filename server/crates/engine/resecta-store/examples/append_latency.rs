#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Ack latency of log appends from concurrent sessions on the SQLite store, with and without
//! group commit, and on PostgreSQL when `RESECTA_TEST_PG` is set; runs interleaved (SQLite off,
//! SQLite on, PostgreSQL, SQLite off, …) on fresh stores.
//!
//! ```text
//! cargo run --release -p resecta-store --example append_latency -- \
//!     [--appenders 20[,8,…]] [--appends 200] [--rounds 3] [--dir DIR]
//! ```
//!
//! Each appender owns one session and appends one ~300-byte edit record at a time, waiting for
//! the acknowledgement before the next (a surgeon's edit waits for its ack); latency is measured
//! around `append`. DIR (default: a temporary directory under the system's) should be on the disk
//! the server's data directory would use: the fsync is what is measured. `--appenders` takes a
//! list: each count is measured in turn.
//!
//! PostgreSQL: `RESECTA_TEST_PG` is the URL of a server where the user may `CREATE DATABASE`
//! (`scripts/pg_cluster.sh start DIR`); the example creates a database for its runs (fresh
//! sessions per run) and drops it at the end. Each append is one transaction (row lock, fence and
//! length check, insert, `COMMIT` with the WAL flushed); "commits" are not counted there.

use std::path::PathBuf;
use std::sync::{Arc, Barrier};
use std::time::Instant;

use resecta_store::{PostgresStore, SessionRecord, SessionStore, SqliteStore, StoreOptions};

/// A translate edit as the plan's event JSON would carry it (~300 bytes), as in benches/store.rs.
fn edit_record(seq: u64) -> String {
    format!(
        r#"{{"type":"move_points","version":{seq},"indices":[[3,4],[3,5],[4,4],[4,5]],"delta_mm":[1.25,-0.5,2.0],"client":"slicer-7f3a","at_ms":1718000000000,"margin_mm":10.0,"band_mm":5.0,"resolution":[40,40],"note":"drag group"}}"#
    )
}

struct Args {
    appenders: Vec<usize>,
    appends: usize,
    rounds: usize,
    dir: Option<PathBuf>,
}

fn args() -> Args {
    let mut a = Args {
        appenders: vec![20],
        appends: 200,
        rounds: 3,
        dir: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_else(|| panic!("{flag} needs a value"));
        match flag.as_str() {
            "--appenders" => {
                a.appenders = value
                    .split(',')
                    .map(|n| n.parse().expect("--appenders N[,N…]"))
                    .collect()
            }
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

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    OnePerAppend,
    GroupCommit,
    Postgres,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::OnePerAppend => "sqlite-1/append",
            Mode::GroupCommit => "sqlite-group",
            Mode::Postgres => "postgres",
        }
    }
}

/// `appenders` threads, each appending `appends` records to its own new session of `store`
/// (ids prefixed `prefix`): every append's latency in ms, and the wall time.
fn run(
    store: &Arc<dyn SessionStore>,
    prefix: &str,
    appenders: usize,
    appends: usize,
) -> (Vec<f64>, f64) {
    for s in 0..appenders {
        store
            .create_session(&SessionRecord {
                id: format!("{prefix}s{s}"),
                display_name: "bench".into(),
                created_ms: 0,
                last_access_ms: 0,
            })
            .unwrap();
    }
    let barrier = Arc::new(Barrier::new(appenders));
    let start = Instant::now();
    let threads: Vec<_> = (0..appenders)
        .map(|s| {
            let (store, barrier, n) = (store.clone(), barrier.clone(), appends);
            let id = format!("{prefix}s{s}");
            std::thread::spawn(move || {
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
    (lat, wall)
}

/// A database of its own on the `RESECTA_TEST_PG` server, dropped at the end.
struct PgDb {
    server: String,
    name: String,
    url: String,
}

impl PgDb {
    fn new(server: &str) -> Self {
        let name = format!("resecta_bench_{}", std::process::id());
        let mut admin = postgres::Client::connect(server, postgres::NoTls).unwrap();
        admin
            .batch_execute(&format!(
                "CREATE DATABASE {name} ENCODING 'UTF8' TEMPLATE template0"
            ))
            .unwrap();
        let (base, query) = server
            .split_once('?')
            .map_or((server, None), |(b, q)| (b, Some(q)));
        let authority_end = base[base.find("://").unwrap() + 3..]
            .find('/')
            .map_or(base.len(), |i| base.find("://").unwrap() + 3 + i);
        let url = match query {
            Some(q) => format!("{}/{name}?{q}", &base[..authority_end]),
            None => format!("{}/{name}", &base[..authority_end]),
        };
        Self {
            server: server.to_owned(),
            name,
            url,
        }
    }
}

impl Drop for PgDb {
    fn drop(&mut self) {
        if let Ok(mut admin) = postgres::Client::connect(&self.server, postgres::NoTls) {
            let _ = admin.batch_execute(&format!(
                "DROP DATABASE IF EXISTS {} WITH (FORCE)",
                self.name
            ));
        }
    }
}

fn main() {
    let a = args();
    let tmp = tempfile::tempdir_in(a.dir.clone().unwrap_or_else(std::env::temp_dir)).unwrap();
    let pg = std::env::var("RESECTA_TEST_PG")
        .ok()
        .filter(|u| !u.is_empty())
        .map(|u| PgDb::new(&u));
    let mut modes = vec![Mode::OnePerAppend, Mode::GroupCommit];
    if pg.is_some() {
        modes.push(Mode::Postgres);
    }
    println!(
        "# appenders {:?} x {} appends of ~300 B, {} rounds, dir {}",
        a.appenders,
        a.appends,
        a.rounds,
        tmp.path().display()
    );
    let pg_store: Option<Arc<dyn SessionStore>> = pg.as_ref().map(|db| {
        let s = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap();
        println!("# postgres: {}", s.target());
        Arc::new(s) as Arc<dyn SessionStore>
    });
    println!(
        "appenders round mode             p50_ms  p90_ms  p99_ms  max_ms  appends/s  commits  appends/commit"
    );
    for &appenders in &a.appenders {
        for round in 1..=a.rounds {
            for &mode in &modes {
                let dir = tmp
                    .path()
                    .join(format!("a{appenders}-r{round}-{}", mode.name()));
                let prefix = format!("a{appenders}r{round}");
                let (lat, wall, commits) = match mode {
                    Mode::OnePerAppend | Mode::GroupCommit => {
                        let sqlite = SqliteStore::open(&dir, StoreOptions::default()).unwrap();
                        let sqlite = Arc::new(if mode == Mode::GroupCommit {
                            sqlite
                        } else {
                            sqlite.without_group_commit()
                        });
                        let before = sqlite.group_commit_stats();
                        let store: Arc<dyn SessionStore> = sqlite.clone();
                        let (lat, wall) = run(&store, &prefix, appenders, a.appends);
                        let commits = sqlite.group_commit_stats().commits - before.commits;
                        (lat, wall, Some(commits))
                    }
                    Mode::Postgres => {
                        let store = pg_store.as_ref().unwrap();
                        let (lat, wall) = run(store, &prefix, appenders, a.appends);
                        (lat, wall, None)
                    }
                };
                let n = lat.len();
                let (commits, per_commit) = match commits {
                    Some(c) => (c.to_string(), format!("{:.2}", n as f64 / c.max(1) as f64)),
                    None => ("-".into(), "-".into()),
                };
                println!(
                    "{appenders:9} {round:5} {:<15} {:7.2} {:7.2} {:7.2} {:7.2} {:10.0} {:>8} {:>15}",
                    mode.name(),
                    percentile(&lat, 50.0),
                    percentile(&lat, 90.0),
                    percentile(&lat, 99.0),
                    lat[n - 1],
                    n as f64 / wall,
                    commits,
                    per_commit,
                );
                if dir.exists() {
                    std::fs::remove_dir_all(&dir).unwrap();
                }
            }
        }
    }
}
