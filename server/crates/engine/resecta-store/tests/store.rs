#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Behaviour of every `SessionStore` backend (one generic function per behaviour, instantiated for
//! SQLite and memory), then SQLite's durability: reopen, corruption, schema checks, kill -9.

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};

use resecta_store::{
    Blob, DB_FILE, LogRecord, MemoryStore, SessionRecord, SessionStore, SqliteStore, StoreError,
    StoreOptions, StoreUsage,
};
use tempfile::TempDir;

fn rec(id: &str, created_ms: i64) -> SessionRecord {
    SessionRecord {
        id: id.to_owned(),
        display_name: format!("Patient {id} Doe"),
        created_ms,
        last_access_ms: created_ms,
    }
}

fn strings(v: impl IntoIterator<Item = impl ToString>) -> Vec<String> {
    v.into_iter().map(|s| s.to_string()).collect()
}

/// nx×ny×nz u8 label map (x fastest), label 1 inside the inscribed ellipsoid with semi-axes 0.4 n.
fn label_map(nx: usize, ny: usize, nz: usize) -> Vec<u8> {
    let mut data = vec![0u8; nx * ny * nz];
    let half = |i: usize, n: usize| (i as f64 + 0.5 - n as f64 / 2.0) / (0.4 * n as f64);
    for (idx, v) in data.iter_mut().enumerate() {
        let (x, y, z) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
        let (u, w, t) = (half(x, nx), half(y, ny), half(z, nz));
        *v = u8::from(u * u + w * w + t * t <= 1.0);
    }
    data
}

// ---- generic behaviour ------------------------------------------------------------------------

fn lifecycle<S: SessionStore>(s: &S) {
    assert!(s.sessions().unwrap().is_empty());
    // Created out of order, with a tie on created_ms broken by id.
    for r in [rec("c", 20), rec("b", 10), rec("a", 20)] {
        s.create_session(&r).unwrap();
    }
    let ids: Vec<String> = s.sessions().unwrap().into_iter().map(|r| r.id).collect();
    assert_eq!(ids, ["b", "a", "c"]);
    assert_eq!(s.session("a").unwrap(), Some(rec("a", 20)));
    assert_eq!(s.session("zz").unwrap(), None);

    s.touch("a", 50).unwrap();
    assert_eq!(s.session("a").unwrap().unwrap().last_access_ms, 50);
    s.touch("a", 30).unwrap(); // never backwards
    assert_eq!(s.session("a").unwrap().unwrap().last_access_ms, 50);
    assert_eq!(s.session("a").unwrap().unwrap().created_ms, 20);

    assert!(s.delete_session("b").unwrap());
    assert!(!s.delete_session("b").unwrap());
    assert_eq!(s.session("b").unwrap(), None);
    let ids: Vec<String> = s.sessions().unwrap().into_iter().map(|r| r.id).collect();
    assert_eq!(ids, ["a", "c"]);
    assert_eq!(s.usage().unwrap().sessions, 2);
}

fn duplicate_id<S: SessionStore>(s: &S) {
    s.create_session(&rec("dup", 1)).unwrap();
    let mut other = rec("dup", 2);
    other.display_name = "Jane Secret".into();
    let err = s.create_session(&other).unwrap_err();
    assert!(
        matches!(&err, StoreError::AlreadyExists { id } if id == "dup"),
        "{err}"
    );
    assert!(!err.to_string().contains("Secret"), "{err}");
    assert_eq!(s.session("dup").unwrap(), Some(rec("dup", 1)));
    assert_eq!(s.sessions().unwrap().len(), 1);
}

fn unknown_session<S: SessionStore>(s: &S) {
    s.create_session(&rec("known", 1)).unwrap();
    let blob = Blob {
        meta_json: "{}".into(),
        data: vec![1, 2, 3],
    };
    let is_not_found = |r: Result<(), StoreError>| match r {
        Err(StoreError::NotFound { id }) => assert_eq!(id, "ghost"),
        other => panic!("expected NotFound, got {other:?}"),
    };
    is_not_found(s.touch("ghost", 5));
    is_not_found(s.put_blob("ghost", "labelmap", &blob));
    is_not_found(s.blob("ghost", "labelmap").map(drop));
    is_not_found(s.delete_blob("ghost", "labelmap").map(drop));
    is_not_found(s.append("ghost", 0, &strings(["{}"])).map(drop));
    is_not_found(s.log("ghost", 0).map(drop));
    is_not_found(s.log_len("ghost").map(drop));
    // Nothing leaked into the known session or created a ghost.
    assert_eq!(s.sessions().unwrap().len(), 1);
    assert_eq!(s.usage().unwrap().stored_bytes, 0);
}

fn limits<S: SessionStore>(s: &S) {
    // Backends are built with max_blob_bytes 1000 and max_record_bytes 100 for this test.
    let bad = |r: Result<(), StoreError>, what: &str| match r {
        Err(e @ (StoreError::Invalid { .. } | StoreError::TooLarge { .. })) => {
            assert!(e.to_string().contains(what), "{e}")
        }
        other => panic!("expected a rejection of {what}, got {other:?}"),
    };
    bad(s.create_session(&rec("", 1)), "session id");
    bad(s.create_session(&rec("a b", 1)), "session id");
    bad(s.create_session(&rec(&"x".repeat(129), 1)), "session id");
    let mut long_name = rec("ok", 1);
    long_name.display_name = "n".repeat(101);
    bad(s.create_session(&long_name), "display name");
    s.create_session(&rec("ok", 1)).unwrap();
    let small = Blob {
        meta_json: String::new(),
        data: vec![7; 1000],
    };
    bad(s.put_blob("ok", "bad/key", &small), "blob key");
    bad(
        s.put_blob(
            "ok",
            "k",
            &Blob {
                meta_json: String::new(),
                data: vec![7; 1001],
            },
        ),
        "blob is 1001 bytes, above the limit of 1000",
    );
    bad(
        s.put_blob(
            "ok",
            "k",
            &Blob {
                meta_json: "m".repeat(101),
                data: Vec::new(),
            },
        ),
        "blob metadata",
    );
    s.put_blob("ok", "k", &small).unwrap();
    let r = s.append("ok", 0, &["a".repeat(100), "b".repeat(101)]);
    bad(r.map(drop), "log record is 101 bytes");
    assert_eq!(
        s.log_len("ok").unwrap(),
        0,
        "a rejected batch appends nothing"
    );
    assert_eq!(s.append("ok", 0, &["a".repeat(100)]).unwrap(), 1);
}

fn blobs<S: SessionStore>(s: &S) {
    s.create_session(&rec("p", 1)).unwrap();
    assert_eq!(s.blob("p", "labelmap").unwrap(), None);
    assert!(!s.delete_blob("p", "labelmap").unwrap());

    let empty = Blob {
        meta_json: String::new(),
        data: Vec::new(),
    };
    s.put_blob("p", "empty", &empty).unwrap();
    assert_eq!(s.blob("p", "empty").unwrap(), Some(empty));

    // 256×256×128 = 8.4 MB, the shape of a real label map at a smaller size.
    let map = Blob {
        meta_json: r#"{"dims":[256,256,128],"spacing":[0.7,0.7,2.5],"type":"u8"}"#.into(),
        data: label_map(256, 256, 128),
    };
    let ones = map.data.iter().filter(|&&v| v == 1).count() as f64;
    let analytic = 4.0 / 3.0 * std::f64::consts::PI * 0.4f64.powi(3) * map.data.len() as f64;
    assert!((ones / analytic - 1.0).abs() < 0.01, "{ones} vs {analytic}");
    s.put_blob("p", "labelmap", &map).unwrap();
    assert_eq!(s.blob("p", "labelmap").unwrap().as_ref(), Some(&map));
    let usage = s.usage().unwrap();
    assert!(
        usage.stored_bytes < map.data.len() as u64 / 20,
        "label map not compressed: {usage:?}"
    );

    // Replace, then delete.
    let small = Blob {
        meta_json: r#"{"v":2}"#.into(),
        data: (0..=255).collect(),
    };
    s.put_blob("p", "labelmap", &small).unwrap();
    assert_eq!(s.blob("p", "labelmap").unwrap(), Some(small.clone()));
    assert!(s.delete_blob("p", "labelmap").unwrap());
    assert_eq!(s.blob("p", "labelmap").unwrap(), None);
    assert!(s.blob("p", "empty").unwrap().is_some());
}

fn append_and_conflict<S: SessionStore>(s: &S) {
    s.create_session(&rec("p", 1)).unwrap();
    assert_eq!(s.log_len("p").unwrap(), 0);
    assert_eq!(s.append("p", 0, &strings(["e1", "e2"])).unwrap(), 2);
    assert_eq!(s.append("p", 2, &strings(["e3"])).unwrap(), 3);
    let before = s.log("p", 0).unwrap();
    for wrong in [0, 2, 4, u64::MAX - 1] {
        match s.append("p", wrong, &strings(["x"])) {
            Err(StoreError::Conflict { expected, actual }) => {
                assert_eq!((expected, actual), (wrong, 3))
            }
            other => panic!("expected Conflict, got {other:?}"),
        }
    }
    assert_eq!(s.log("p", 0).unwrap(), before);
    assert_eq!(s.append("p", 3, &[]).unwrap(), 3);
    assert!(matches!(
        s.append("p", 1, &[]),
        Err(StoreError::Conflict { .. })
    ));
    let all: Vec<LogRecord> = (1..=3)
        .map(|seq| LogRecord {
            seq,
            json: format!("e{seq}"),
        })
        .collect();
    assert_eq!(before, all);
    assert_eq!(s.log("p", 1).unwrap(), all[1..]);
    assert!(s.log("p", 3).unwrap().is_empty());
    assert!(s.log("p", u64::MAX).unwrap().is_empty());
    // Logs are per session.
    s.create_session(&rec("q", 2)).unwrap();
    assert_eq!(s.append("q", 0, &strings(["q1"])).unwrap(), 1);
    assert_eq!(s.log_len("p").unwrap(), 3);
}

/// Several threads race appends with the length they last saw; every position is won once.
fn concurrent_appends<S: SessionStore>(s: &S) {
    const THREADS: usize = 4;
    const EACH: usize = 25;
    s.create_session(&rec("race", 1)).unwrap();
    let won: Vec<Vec<u64>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..THREADS)
            .map(|t| {
                scope.spawn(move || {
                    let (mut positions, mut conflicts) = (Vec::new(), 0);
                    while positions.len() < EACH {
                        let len = s.log_len("race").unwrap();
                        let json = format!("t{t}-{}", positions.len());
                        match s.append("race", len, &[json]) {
                            Ok(n) => {
                                assert_eq!(n, len + 1);
                                positions.push(n);
                            }
                            Err(StoreError::Conflict { expected, actual }) => {
                                assert_eq!(expected, len);
                                assert!(actual > len);
                                conflicts += 1;
                            }
                            Err(e) => panic!("{e}"),
                        }
                    }
                    let _ = conflicts;
                    positions
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let total = (THREADS * EACH) as u64;
    let mut all: Vec<u64> = won.iter().flatten().copied().collect();
    all.sort_unstable();
    assert_eq!(
        all,
        (1..=total).collect::<Vec<_>>(),
        "each position won once"
    );
    let log = s.log("race", 0).unwrap();
    assert_eq!(log.len() as u64, total);
    for (t, positions) in won.iter().enumerate() {
        for (k, &seq) in positions.iter().enumerate() {
            assert_eq!(log[seq as usize - 1].seq, seq);
            assert_eq!(log[seq as usize - 1].json, format!("t{t}-{k}"));
        }
    }
}

fn idle<S: SessionStore>(s: &S) {
    for (id, t) in [("a", 100), ("b", 50), ("c", 200), ("d", 50)] {
        s.create_session(&rec(id, t)).unwrap();
    }
    assert!(s.idle_since(50).unwrap().is_empty());
    assert_eq!(s.idle_since(51).unwrap(), ["b", "d"]);
    assert_eq!(s.idle_since(101).unwrap(), ["b", "d", "a"]);
    s.touch("b", 300).unwrap();
    assert_eq!(s.idle_since(201).unwrap(), ["d", "a", "c"]);
}

fn delete_cascades<S: SessionStore>(s: &S) {
    s.create_session(&rec("gone", 1)).unwrap();
    s.create_session(&rec("kept", 2)).unwrap();
    let blob = Blob {
        meta_json: "{}".into(),
        data: vec![3; 5000],
    };
    for id in ["gone", "kept"] {
        s.put_blob(id, "labelmap", &blob).unwrap();
        s.append(id, 0, &strings(["a", "b"])).unwrap();
    }
    let both = s.usage().unwrap();
    assert!(s.delete_session("gone").unwrap());
    let kept = s.usage().unwrap();
    assert_eq!(kept.sessions, 1);
    assert_eq!(kept.stored_bytes * 2, both.stored_bytes);
    // The id can be reused and starts empty.
    s.create_session(&rec("gone", 3)).unwrap();
    assert_eq!(s.blob("gone", "labelmap").unwrap(), None);
    assert_eq!(s.log_len("gone").unwrap(), 0);
    assert_eq!(s.append("gone", 0, &strings(["fresh"])).unwrap(), 1);
    assert_eq!(s.log("kept", 0).unwrap().len(), 2);
    assert!(s.delete_session("gone").unwrap());
    assert!(s.delete_session("kept").unwrap());
    assert_eq!(s.usage().unwrap(), StoreUsage::default());
}

fn usage_counts<S: SessionStore>(s: &S) {
    s.create_session(&rec("u", 1)).unwrap();
    s.append("u", 0, &strings(["12345", "678"])).unwrap();
    s.put_blob(
        "u",
        "m",
        &Blob {
            meta_json: "meta".into(),
            data: Vec::new(),
        },
    )
    .unwrap();
    let u = s.usage().unwrap();
    assert_eq!(u.sessions, 1);
    // 8 log bytes + 4 meta bytes + an empty zstd frame (header and an empty block, < 20 bytes).
    assert!(
        (12 + 8..12 + 20).contains(&u.stored_bytes),
        "{}",
        u.stored_bytes
    );
}

fn object_safe(s: &dyn SessionStore) {
    s.create_session(&rec("dyn", 1)).unwrap();
    assert_eq!(s.append("dyn", 0, &strings(["x"])).unwrap(), 1);
    assert!(format!("{s:?}").contains("Store"));
}

fn small_limits() -> StoreOptions {
    StoreOptions {
        max_blob_bytes: 1000,
        max_record_bytes: 100,
        ..StoreOptions::default()
    }
}

macro_rules! backend_tests {
    ($backend:ident, $make:expr) => {
        mod $backend {
            use super::*;
            #[test]
            fn lifecycle() {
                let (s, _dir) = $make(StoreOptions::default());
                super::lifecycle(&s);
            }
            #[test]
            fn duplicate_id() {
                let (s, _dir) = $make(StoreOptions::default());
                super::duplicate_id(&s);
            }
            #[test]
            fn unknown_session() {
                let (s, _dir) = $make(StoreOptions::default());
                super::unknown_session(&s);
            }
            #[test]
            fn limits() {
                let (s, _dir) = $make(small_limits());
                super::limits(&s);
            }
            #[test]
            fn blobs() {
                let (s, _dir) = $make(StoreOptions::default());
                super::blobs(&s);
            }
            #[test]
            fn append_and_conflict() {
                let (s, _dir) = $make(StoreOptions::default());
                super::append_and_conflict(&s);
            }
            #[test]
            fn concurrent_appends() {
                let (s, _dir) = $make(StoreOptions::default());
                super::concurrent_appends(&s);
            }
            #[test]
            fn idle() {
                let (s, _dir) = $make(StoreOptions::default());
                super::idle(&s);
            }
            #[test]
            fn delete_cascades() {
                let (s, _dir) = $make(StoreOptions::default());
                super::delete_cascades(&s);
            }
            #[test]
            fn usage_counts() {
                let (s, _dir) = $make(StoreOptions::default());
                super::usage_counts(&s);
            }
            #[test]
            fn object_safe() {
                let (s, _dir) = $make(StoreOptions::default());
                super::object_safe(&s);
            }
        }
    };
}

fn sqlite(opts: StoreOptions) -> (SqliteStore, TempDir) {
    let dir = tempfile::tempdir().unwrap();
    (SqliteStore::open(dir.path(), opts).unwrap(), dir)
}

fn memory(opts: StoreOptions) -> (MemoryStore, ()) {
    (MemoryStore::new(opts), ())
}

backend_tests!(on_sqlite, sqlite);
backend_tests!(on_memory, memory);

// ---- SQLite durability ------------------------------------------------------------------------

type Snapshot = Vec<(SessionRecord, Vec<(String, Option<Blob>)>, Vec<LogRecord>)>;

fn snapshot(s: &impl SessionStore, keys: &[&str]) -> Snapshot {
    s.sessions()
        .unwrap()
        .into_iter()
        .map(|r| {
            let blobs = keys
                .iter()
                .map(|k| (k.to_string(), s.blob(&r.id, k).unwrap()))
                .collect();
            let log = s.log(&r.id, 0).unwrap();
            (r, blobs, log)
        })
        .collect()
}

#[test]
fn sqlite_reopen_restores_everything() {
    let dir = tempfile::tempdir().unwrap();
    let keys = ["labelmap", "models"];
    let before = {
        let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
        for (i, id) in ["s1", "s2", "s3"].iter().enumerate() {
            let mut r = rec(id, 1000 - i as i64);
            r.display_name = format!("Ünïcode näme {i} 🫀");
            s.create_session(&r).unwrap();
            s.touch(id, 5000 + i as i64).unwrap();
            for batch in 0..=i {
                let len = s.log_len(id).unwrap();
                let recs: Vec<String> = (0..3)
                    .map(|k| format!(r#"{{"op":"move","batch":{batch},"k":{k}}}"#))
                    .collect();
                s.append(id, len, &recs).unwrap();
            }
        }
        let map = Blob {
            meta_json: r#"{"dims":[64,64,32]}"#.into(),
            data: label_map(64, 64, 32),
        };
        s.put_blob("s1", "labelmap", &map).unwrap();
        s.put_blob(
            "s2",
            "models",
            &Blob {
                meta_json: "{}".into(),
                data: (0..10_000u32)
                    .flat_map(|v| v.wrapping_mul(2_654_435_761).to_le_bytes())
                    .collect(),
            },
        )
        .unwrap();
        s.delete_session("s3").unwrap();
        let snap = snapshot(&s, &keys);
        assert_eq!(snap.len(), 2);
        (snap, s.usage().unwrap())
    };
    let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    assert_eq!((snapshot(&s, &keys), s.usage().unwrap()), before);
    assert_eq!(s.sessions().unwrap()[0].last_access_ms, 5001);
    assert_eq!(s.log_len("s2").unwrap(), 6);
    assert_eq!(s.append("s2", 6, &strings(["{}"])).unwrap(), 7);
    assert!(s.path().ends_with(DB_FILE));
}

#[test]
fn sqlite_two_stores_on_one_dir_see_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let a = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    let b = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    a.create_session(&rec("x", 1)).unwrap();
    assert_eq!(b.append("x", 0, &strings(["1"])).unwrap(), 1);
    assert!(matches!(
        a.append("x", 0, &strings(["1"])),
        Err(StoreError::Conflict {
            expected: 0,
            actual: 1
        })
    ));
}

#[test]
fn sqlite_garbage_file_is_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let noise: Vec<u8> = (0..20_000u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    std::fs::write(dir.path().join(DB_FILE), &noise).unwrap();
    let err = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap_err();
    assert!(matches!(err, StoreError::Corrupt { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains(DB_FILE) && msg.contains("not a database"),
        "{msg}"
    );
}

#[test]
fn sqlite_damaged_pages_give_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    {
        let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
        for i in 0..20 {
            let id = format!("s{i}");
            s.create_session(&rec(&id, i)).unwrap();
            let recs: Vec<String> = (0..50)
                .map(|k| format!(r#"{{"edit":{k},"pad":"{}"}}"#, "x".repeat(200)))
                .collect();
            s.append(&id, 0, &recs).unwrap();
        }
    } // closing the last connection checkpoints the WAL into the main file
    let path = dir.path().join(DB_FILE);
    let mut bytes = std::fs::read(&path).unwrap();
    assert!(bytes.len() > 100_000, "{}", bytes.len());
    // Keep page 1 (header and schema), scramble every later page's first half.
    let page = 4096;
    for p in (page..bytes.len()).step_by(page) {
        for (k, b) in bytes[p..p + page / 2].iter_mut().enumerate() {
            *b = (k as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3] ^ 0x5a;
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let outcome = SqliteStore::open(dir.path(), StoreOptions::default()).and_then(|s| {
        s.sessions()?;
        for i in 0..20 {
            s.log(&format!("s{i}"), 0)?;
        }
        Ok(())
    });
    let err = outcome.expect_err("scrambled pages went unnoticed");
    assert!(matches!(err, StoreError::Corrupt { .. }), "{err}");
}

#[test]
fn sqlite_foreign_or_newer_schema_is_refused() {
    let foreign = tempfile::tempdir().unwrap();
    {
        let c = rusqlite::Connection::open(foreign.path().join(DB_FILE)).unwrap();
        c.execute_batch("CREATE TABLE notes (t TEXT); PRAGMA user_version = 7;")
            .unwrap();
    }
    let err = SqliteStore::open(foreign.path(), StoreOptions::default()).unwrap_err();
    assert!(
        matches!(&err, StoreError::Corrupt { detail } if detail.contains("another application")),
        "{err}"
    );

    let unversioned = tempfile::tempdir().unwrap();
    {
        let c = rusqlite::Connection::open(unversioned.path().join(DB_FILE)).unwrap();
        c.execute_batch("CREATE TABLE notes (t TEXT);").unwrap();
    }
    let err = SqliteStore::open(unversioned.path(), StoreOptions::default()).unwrap_err();
    assert!(matches!(err, StoreError::Corrupt { .. }), "{err}");

    let newer = tempfile::tempdir().unwrap();
    drop(SqliteStore::open(newer.path(), StoreOptions::default()).unwrap());
    {
        let c = rusqlite::Connection::open(newer.path().join(DB_FILE)).unwrap();
        c.pragma_update(None, "user_version", 2).unwrap();
    }
    let err = SqliteStore::open(newer.path(), StoreOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::SchemaTooNew {
                found: 2,
                supported: 1
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("newer"), "{err}");
}

#[test]
fn sqlite_blob_inflation_is_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let data = label_map(40, 40, 40);
    {
        let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
        s.create_session(&rec("p", 1)).unwrap();
        for key in ["ok", "garbled", "lying", "huge"] {
            s.put_blob(
                "p",
                key,
                &Blob {
                    meta_json: "{}".into(),
                    data: data.clone(),
                },
            )
            .unwrap();
        }
    }
    {
        let c = rusqlite::Connection::open(dir.path().join(DB_FILE)).unwrap();
        c.execute(
            "UPDATE blobs SET data = zeroblob(64) WHERE key = 'garbled'",
            [],
        )
        .unwrap();
        c.execute(
            "UPDATE blobs SET raw_len = raw_len - 1 WHERE key = 'lying'",
            [],
        )
        .unwrap();
        c.execute("UPDATE blobs SET raw_len = 1 << 40 WHERE key = 'huge'", [])
            .unwrap();
    }
    let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    assert_eq!(s.blob("p", "ok").unwrap().unwrap().data, data);
    for key in ["garbled", "lying"] {
        let err = s.blob("p", key).unwrap_err();
        assert!(matches!(err, StoreError::Corrupt { .. }), "{key}: {err}");
    }
    let err = s.blob("p", "huge").unwrap_err();
    assert!(
        matches!(err, StoreError::TooLarge { size, .. } if size == 1 << 40),
        "{err}"
    );
    // A store opened with a lower limit refuses to inflate what an earlier one accepted.
    let strict = SqliteStore::open(
        dir.path(),
        StoreOptions {
            max_blob_bytes: 1000,
            ..StoreOptions::default()
        },
    )
    .unwrap();
    let err = strict.blob("p", "ok").unwrap_err();
    assert!(
        matches!(err, StoreError::TooLarge { limit: 1000, .. }),
        "{err}"
    );
}

// ---- kill -9 during an append burst -----------------------------------------------------------

const CHILD_DIR_ENV: &str = "RESECTA_STORE_KILL_CHILD_DIR";
const KILL_SESSION: &str = "burst";

/// Batch size after a log of `len` records: 1, 2 or 3, so a torn batch would show.
fn batch_after(len: u64) -> u64 {
    1 + len % 3
}

fn edit_json(seq: u64) -> String {
    format!(
        r#"{{"op":"translate","seq":{seq},"pad":"{}"}}"#,
        "p".repeat(seq as usize % 200)
    )
}

/// Child half of `kill_9_loses_no_acknowledged_append`: appends until killed, printing each
/// acknowledged length. Does nothing when run as an ordinary test.
#[test]
fn kill_child_appender() {
    let Some(dir) = std::env::var_os(CHILD_DIR_ENV) else {
        return;
    };
    let s = SqliteStore::open(Path::new(&dir), StoreOptions::default()).unwrap();
    if s.session(KILL_SESSION).unwrap().is_none() {
        s.create_session(&rec(KILL_SESSION, 0)).unwrap();
    }
    let mut len = s.log_len(KILL_SESSION).unwrap();
    let mut out = std::io::stdout().lock();
    loop {
        let recs: Vec<String> = (len + 1..=len + batch_after(len)).map(edit_json).collect();
        len = s.append(KILL_SESSION, len, &recs).unwrap();
        writeln!(out, "acked {len}").unwrap();
        out.flush().unwrap();
    }
}

#[test]
fn kill_9_loses_no_acknowledged_append() {
    let dir = tempfile::tempdir().unwrap();
    let exe = std::env::current_exe().unwrap();
    let mut acked = 0u64;
    for round in 0..4u64 {
        let mut child = Command::new(&exe)
            .args([
                "kill_child_appender",
                "--exact",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD_DIR_ENV, dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let kill_after = acked + 100 + 37 * round;
        let mut killed = false;
        for line in lines {
            let line = line.unwrap();
            let Some(n) = line.strip_prefix("acked ") else {
                continue;
            };
            let n: u64 = n.parse().unwrap();
            assert!(n > acked, "acks must grow: {n} after {acked}");
            acked = n;
            if !killed && acked >= kill_after {
                child.kill().unwrap(); // SIGKILL, mid-burst; acks already printed are still read
                killed = true;
            }
        }
        assert!(killed, "child ended on its own (round {round})");
        let status = child.wait().unwrap();
        assert!(!status.success());

        let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
        let log = s.log(KILL_SESSION, 0).unwrap();
        let len = log.len() as u64;
        assert!(
            len >= acked,
            "round {round}: log has {len} records, {acked} were acknowledged"
        );
        assert!(
            len <= acked + 3,
            "round {round}: {len} records, at most one unacknowledged batch"
        );
        for (i, r) in log.iter().enumerate() {
            assert_eq!(r.seq, i as u64 + 1);
            assert_eq!(r.json, edit_json(r.seq));
        }
        // Batches are atomic: the length is a batch boundary.
        let mut boundary = 0;
        while boundary < len {
            boundary += batch_after(boundary);
        }
        assert_eq!(boundary, len, "round {round}: torn batch");
        assert_eq!(s.log_len(KILL_SESSION).unwrap(), len);
        acked = len;
    }
}

#[test]
fn errors_name_quantities_not_contents() {
    let s = MemoryStore::new(small_limits());
    let mut r = rec("p1", 1);
    r.display_name = "Ola Nordmann".into();
    s.create_session(&r).unwrap();
    let secret = Blob {
        meta_json: r#"{"name":"Ola Nordmann"}"#.into(),
        data: b"Ola Nordmann".repeat(100),
    };
    let errors = [
        s.create_session(&r).unwrap_err(),
        s.put_blob("p1", "k", &secret).unwrap_err(),
        s.append("p1", 0, &["Ola Nordmann".repeat(10)]).unwrap_err(),
        s.append("p1", 5, &strings(["Ola Nordmann"])).unwrap_err(),
    ];
    let kinds: BTreeSet<String> = errors
        .iter()
        .map(|e| {
            format!("{e:?}")
                .split([' ', '{'])
                .next()
                .unwrap()
                .to_owned()
        })
        .collect();
    assert_eq!(kinds.len(), 3, "{kinds:?}");
    for e in &errors {
        assert!(!e.to_string().contains("Ola"), "{e}");
        assert!(!format!("{e:?}").contains("Ola"), "{e:?}");
    }
    assert!(!format!("{secret:?}").contains("Ola"));
    assert!(!format!("{r:?}").contains("Ola"));
    s.put_blob(
        "p1",
        "m",
        &Blob {
            meta_json: "Ola".into(),
            data: b"Ola".to_vec(),
        },
    )
    .unwrap();
    s.append("p1", 0, &strings(["Ola"])).unwrap();
    assert!(!format!("{s:?}").contains("Ola"), "{s:?}");
}

/// Concurrent appends share commits, and in one batch each append succeeds or fails on its own:
/// 10 sessions appended to by one thread each, and 10 threads racing for position 1 of one
/// session (one wins, nine conflict), all released at once, 20 rounds.
#[test]
fn sqlite_group_commit_shares_commits_and_keeps_appends_apart() {
    const OWN: usize = 10;
    const RACERS: usize = 10;
    const ROUNDS: u64 = 20;
    let (s, dir) = sqlite(StoreOptions::default());
    for i in 0..OWN {
        s.create_session(&rec(&format!("own{i}"), 1)).unwrap();
    }
    for r in 0..ROUNDS {
        s.create_session(&rec(&format!("race{r}"), 1)).unwrap();
    }
    let barrier = std::sync::Barrier::new(OWN + RACERS);
    let winners: Vec<usize> = std::thread::scope(|scope| {
        let own: Vec<_> = (0..OWN)
            .map(|i| {
                let (s, barrier) = (&s, &barrier);
                scope.spawn(move || {
                    for r in 0..ROUNDS {
                        barrier.wait();
                        let id = format!("own{i}");
                        assert_eq!(s.append(&id, r, &[format!("{i}-{r}")]).unwrap(), r + 1);
                    }
                })
            })
            .collect();
        let racers: Vec<_> = (0..RACERS)
            .map(|t| {
                let (s, barrier) = (&s, &barrier);
                scope.spawn(move || {
                    let mut won = 0;
                    for r in 0..ROUNDS {
                        barrier.wait();
                        match s.append(&format!("race{r}"), 0, &[format!("t{t}")]) {
                            Ok(1) => won += 1,
                            Err(StoreError::Conflict {
                                expected: 0,
                                actual: 1,
                            }) => {}
                            other => panic!("{other:?}"),
                        }
                    }
                    won
                })
            })
            .collect();
        own.into_iter().for_each(|h| h.join().unwrap());
        racers.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(winners.iter().sum::<usize>() as u64, ROUNDS);
    let stats = s.group_commit_stats();
    let appends = ROUNDS * (OWN + RACERS) as u64;
    assert_eq!(stats.appends, appends);
    assert!(
        stats.commits < appends / 2,
        "{stats:?}: concurrent appends did not share commits"
    );
    // Everything acknowledged is there after a reopen, each log exactly as appended.
    drop(s);
    let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    for i in 0..OWN {
        let log = s.log(&format!("own{i}"), 0).unwrap();
        let want: Vec<String> = (0..ROUNDS).map(|r| format!("{i}-{r}")).collect();
        assert_eq!(log.iter().map(|l| l.json.clone()).collect::<Vec<_>>(), want);
    }
    for r in 0..ROUNDS {
        assert_eq!(s.log_len(&format!("race{r}")).unwrap(), 1);
    }
    // A batch of one behaves the same.
    let s = s.without_group_commit();
    assert_eq!(
        s.append("own0", ROUNDS, &strings(["x"])).unwrap(),
        ROUNDS + 1
    );
    assert!(matches!(
        s.append("own0", 0, &strings(["y"])),
        Err(StoreError::Conflict { .. })
    ));
    assert!(matches!(
        s.append("ghost", 0, &strings(["y"])),
        Err(StoreError::NotFound { .. })
    ));
}
