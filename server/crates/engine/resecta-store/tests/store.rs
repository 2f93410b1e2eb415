#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Behaviour of every `SessionStore` backend (one generic function per behaviour, instantiated for
//! SQLite, memory and PostgreSQL), leases on two handles of one store, then SQLite's durability
//! (reopen, corruption, schema checks, kill -9) and PostgreSQL's (reopen, schema, passwords, TLS).
//!
//! The PostgreSQL tests need `RESECTA_TEST_PG`, the URL of a server where the user may
//! `CREATE DATABASE` (`scripts/pg_cluster.sh start DIR` makes one); each test creates a database
//! of its own and drops it. Without the variable they print `SKIPPED: RESECTA_TEST_PG not set`
//! and pass, except when `CI` is set: then they fail. The TLS tests also need
//! `RESECTA_TEST_PG_CA`, the CA of the server's certificate (pg_cluster.sh's, for "localhost").

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};

use resecta_store::{
    Blob, Claim, DB_FILE, Lease, LogRecord, MemoryStore, PostgresStore, Replica, SCHEMA_VERSION,
    SessionRecord, SessionStore, SqliteStore, StoreError, StoreOptions, StoreUsage,
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

// ---- leases: two handles on one store, as two replicas ----------------------------------------

fn replica(name: &str) -> Replica {
    Replica {
        id: name.to_owned(),
        grpc: format!("{name}.internal:50051"),
        http: format!("https://{name}.internal:8443"),
    }
}

fn held_by(c: Claim) -> Lease {
    match c {
        Claim::Held(lease) => lease,
        Claim::Granted { token } => panic!("expected Held, got Granted {{ token: {token} }}"),
    }
}

fn lease_grant_and_held<S: SessionStore>(a: &S, b: &S) {
    let (ra, rb) = (replica("a"), replica("b"));
    a.create_session(&rec("L", 1)).unwrap();
    assert_eq!(a.lease("L").unwrap(), None);
    assert_eq!(
        a.claim("L", &ra, 60_000).unwrap(),
        Claim::Granted { token: 1 }
    );
    for s in [a, b] {
        let lease = s.lease("L").unwrap().unwrap();
        assert_eq!((&lease.holder, lease.token), (&ra, 1));
        assert!((50_000..=60_000).contains(&lease.remaining_ms), "{lease:?}");
    }
    let held = held_by(b.claim("L", &rb, 60_000).unwrap());
    assert_eq!((&held.holder, held.token), (&ra, 1));
    assert!((50_000..=60_000).contains(&held.remaining_ms), "{held:?}");
    // The holder's claim renews with the same token; so does another handle of the same replica.
    for s in [a, b] {
        assert_eq!(
            s.claim("L", &ra, 60_000).unwrap(),
            Claim::Granted { token: 1 }
        );
    }
    // Unknown sessions.
    let ghost = a.claim("ghost", &ra, 60_000).unwrap_err();
    assert!(
        matches!(&ghost, StoreError::NotFound { id } if id == "ghost"),
        "{ghost}"
    );
    assert!(matches!(a.lease("ghost"), Err(StoreError::NotFound { .. })));
    assert!(!a.release("ghost", "a").unwrap());
    assert_eq!(a.renew("a", &strings(["ghost"]), 1000).unwrap(), ["ghost"]);
}

/// The paused old owner: its lease expires, another replica takes the session over, and the old
/// owner's late writes are refused with `Fenced`, leaving the log as the new owner wrote it.
fn lease_expiry_fences_the_old_holder<S: SessionStore>(a: &S, b: &S) {
    let (ra, rb) = (replica("a"), replica("b"));
    a.create_session(&rec("L", 1)).unwrap();
    assert_eq!(a.claim("L", &ra, 150).unwrap(), Claim::Granted { token: 1 });
    assert_eq!(a.append("L", 0, &strings(["a1"])).unwrap(), 1);
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(b.lease("L").unwrap(), None, "expired");
    assert_eq!(
        b.claim("L", &rb, 60_000).unwrap(),
        Claim::Granted { token: 2 }
    );
    assert_eq!(b.append("L", 1, &strings(["b2"])).unwrap(), 2);
    let blob = Blob {
        meta_json: "{}".into(),
        data: vec![1; 100],
    };
    let fenced = |r: Result<(), StoreError>| match r {
        Err(StoreError::Fenced { id }) => assert_eq!(id, "L"),
        other => panic!("expected Fenced, got {other:?}"),
    };
    fenced(a.append("L", 1, &strings(["late"])).map(drop));
    fenced(a.append("L", 2, &strings(["late"])).map(drop));
    fenced(a.append("L", 2, &[]).map(drop));
    fenced(a.put_blob("L", "labelmap", &blob));
    fenced(a.delete_blob("L", "labelmap").map(drop));
    fenced(a.delete_session("L").map(drop));
    let log: Vec<String> = b.log("L", 0).unwrap().into_iter().map(|r| r.json).collect();
    assert_eq!(log, ["a1", "b2"]);
    assert_eq!(b.blob("L", "labelmap").unwrap(), None);
    assert!(b.session("L").unwrap().is_some());
    let held = held_by(a.claim("L", &ra, 60_000).unwrap());
    assert_eq!((&held.holder, held.token), (&rb, 2));
    // The old holder learns it lost the lease; the new one renews.
    assert_eq!(a.renew("a", &strings(["L"]), 60_000).unwrap(), ["L"]);
    assert!(b.renew("b", &strings(["L"]), 60_000).unwrap().is_empty());
    b.put_blob("L", "labelmap", &blob).unwrap();
    assert_eq!(b.append("L", 2, &strings(["b3"])).unwrap(), 3);
}

fn lease_renew<S: SessionStore>(a: &S, b: &S) {
    let (ra, rb) = (replica("a"), replica("b"));
    for id in ["L", "M", "N"] {
        a.create_session(&rec(id, 1)).unwrap();
    }
    assert_eq!(a.claim("L", &ra, 150).unwrap(), Claim::Granted { token: 1 });
    assert_eq!(a.claim("M", &ra, 150).unwrap(), Claim::Granted { token: 1 });
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(a.lease("L").unwrap(), None);
    // Expired but not taken over: renewal keeps them; N was never claimed by this handle.
    assert_eq!(
        a.renew("a", &strings(["L", "M", "N"]), 60_000).unwrap(),
        ["N"]
    );
    for id in ["L", "M"] {
        let held = held_by(b.claim(id, &rb, 60_000).unwrap());
        assert_eq!((&held.holder, held.token), (&ra, 1));
        assert!(held.remaining_ms > 50_000, "{held:?}");
    }
    // The same holder claiming again after expiry keeps its token.
    assert_eq!(a.claim("M", &ra, 150).unwrap(), Claim::Granted { token: 1 });
    // Another replica id cannot renew a's lease.
    assert_eq!(a.renew("b", &strings(["L"]), 60_000).unwrap(), ["L"]);
    assert_eq!(a.lease("L").unwrap().unwrap().holder, ra);
    // Lost to another holder: reported, and this handle's writes stay fenced after the report
    // (a write racing the report must not slip through as a mere length conflict).
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(matches!(
        b.claim("M", &rb, 60_000).unwrap(),
        Claim::Granted { .. }
    ));
    assert_eq!(a.renew("a", &strings(["M"]), 60_000).unwrap(), ["M"]);
    let e = a.append("M", 0, &strings(["late"])).unwrap_err();
    assert!(matches!(e, StoreError::Fenced { .. }), "{e}");
    assert_eq!(b.log_len("M").unwrap(), 0);
}

fn lease_release<S: SessionStore>(a: &S, b: &S) {
    let (ra, rb) = (replica("a"), replica("b"));
    a.create_session(&rec("L", 1)).unwrap();
    assert_eq!(
        a.claim("L", &ra, 60_000).unwrap(),
        Claim::Granted { token: 1 }
    );
    held_by(b.claim("L", &rb, 60_000).unwrap());
    assert!(!b.release("L", "b").unwrap(), "b does not hold it");
    assert!(a.release("L", "a").unwrap());
    assert!(!a.release("L", "a").unwrap(), "released already");
    assert_eq!(b.lease("L").unwrap(), None);
    // Another replica's claim succeeds at once, with a larger token.
    assert_eq!(
        b.claim("L", &rb, 60_000).unwrap(),
        Claim::Granted { token: 2 }
    );
    let held = held_by(a.claim("L", &ra, 60_000).unwrap());
    assert_eq!((&held.holder, held.token), (&rb, 2));
}

fn lease_delete_cascades<S: SessionStore>(a: &S, b: &S) {
    let (ra, rb) = (replica("a"), replica("b"));
    a.create_session(&rec("L", 1)).unwrap();
    assert_eq!(
        a.claim("L", &ra, 60_000).unwrap(),
        Claim::Granted { token: 1 }
    );
    assert_eq!(a.append("L", 0, &strings(["x"])).unwrap(), 1);
    assert!(a.delete_session("L").unwrap());
    assert!(matches!(b.lease("L"), Err(StoreError::NotFound { .. })));
    assert!(matches!(
        b.claim("L", &rb, 60_000),
        Err(StoreError::NotFound { .. })
    ));
    // A new session of the same id starts without a lease.
    b.create_session(&rec("L", 2)).unwrap();
    assert_eq!(a.lease("L").unwrap(), None);
    assert_eq!(
        b.claim("L", &rb, 60_000).unwrap(),
        Claim::Granted { token: 1 }
    );
    assert_eq!(a.usage().unwrap().sessions, 1);
}

fn small_limits() -> StoreOptions {
    StoreOptions {
        max_blob_bytes: 1000,
        max_record_bytes: 100,
        ..StoreOptions::default()
    }
}

/// One test per behaviour, each on a store `$make` opens with `$opts`.
macro_rules! on_one_store {
    ($make:path, $opts:expr; $($behaviour:ident),+) => {$(
        #[test]
        fn $behaviour() {
            let Some((s, _dir)) = $make($opts) else {
                return;
            };
            super::$behaviour(&s);
        }
    )+};
}

/// One test per behaviour, each on two handles `$pair` opens on one store (two replicas).
macro_rules! on_two_handles {
    ($pair:path; $($behaviour:ident),+) => {$(
        #[test]
        fn $behaviour() {
            let Some((a, b, _dir)) = $pair() else {
                return;
            };
            super::$behaviour(&a, &b);
        }
    )+};
}

macro_rules! backend_tests {
    ($module:ident, $make:path, $pair:path) => {
        mod $module {
            use super::*;

            on_one_store!($make, StoreOptions::default(); lifecycle, duplicate_id, unknown_session,
                blobs, append_and_conflict, concurrent_appends, idle, delete_cascades, usage_counts);
            on_one_store!($make, small_limits(); limits);
            on_two_handles!($pair; lease_grant_and_held, lease_expiry_fences_the_old_holder,
                lease_renew, lease_release, lease_delete_cascades);

            #[test]
            fn object_safe() {
                let Some((s, _dir)) = $make(StoreOptions::default()) else {
                    return;
                };
                super::object_safe(&s);
            }
        }
    };
}

fn sqlite(opts: StoreOptions) -> Option<(SqliteStore, TempDir)> {
    let dir = tempfile::tempdir().unwrap();
    Some((SqliteStore::open(dir.path(), opts).unwrap(), dir))
}

/// Two stores on one directory, as two replicas sharing a disk would open it.
fn sqlite_pair() -> Option<(SqliteStore, SqliteStore, TempDir)> {
    let dir = tempfile::tempdir().unwrap();
    let a = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    let b = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    Some((a, b, dir))
}

fn memory(opts: StoreOptions) -> Option<(MemoryStore, ())> {
    Some((MemoryStore::new(opts), ()))
}

fn memory_pair() -> Option<(MemoryStore, MemoryStore, ())> {
    let a = MemoryStore::new(StoreOptions::default());
    let b = a.share();
    Some((a, b, ()))
}

fn postgres(opts: StoreOptions) -> Option<(PostgresStore, pg::Db)> {
    let db = pg::Db::new()?;
    Some((PostgresStore::open(&db.url, None, opts).unwrap(), db))
}

/// Two stores (two pools) on one database, as two replicas open it.
fn postgres_pair() -> Option<(PostgresStore, PostgresStore, pg::Db)> {
    let db = pg::Db::new()?;
    let a = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap();
    let b = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap();
    Some((a, b, db))
}

backend_tests!(on_sqlite, sqlite, sqlite_pair);
backend_tests!(on_memory, memory, memory_pair);
backend_tests!(on_postgres, postgres, postgres_pair);

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

/// What a store held is there again when `open` opens it anew: sessions, access times, logs,
/// blobs, leases; deletions stay deleted.
fn reopen_restores_everything<S: SessionStore>(open: impl Fn() -> S) {
    let keys = ["labelmap", "models"];
    let before = {
        let s = open();
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
        s.claim("s2", &replica("a"), 60_000).unwrap();
        s.delete_session("s3").unwrap();
        let snap = snapshot(&s, &keys);
        assert_eq!(snap.len(), 2);
        (snap, s.usage().unwrap())
    };
    let s = open();
    assert_eq!((snapshot(&s, &keys), s.usage().unwrap()), before);
    assert_eq!(s.sessions().unwrap()[0].last_access_ms, 5001);
    assert_eq!(s.log_len("s2").unwrap(), 6);
    assert_eq!(s.append("s2", 6, &strings(["{}"])).unwrap(), 7);
    assert_eq!(s.lease("s2").unwrap().unwrap().holder, replica("a"));
}

#[test]
fn sqlite_reopen_restores_everything() {
    let dir = tempfile::tempdir().unwrap();
    reopen_restores_everything(|| SqliteStore::open(dir.path(), StoreOptions::default()).unwrap());
    let s = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
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
        c.pragma_update(None, "user_version", SCHEMA_VERSION + 1)
            .unwrap();
    }
    let err = SqliteStore::open(newer.path(), StoreOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::SchemaTooNew { found, supported }
                if found == SCHEMA_VERSION + 1 && supported == SCHEMA_VERSION
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
    let (s, dir) = sqlite(StoreOptions::default()).unwrap();
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

// ---- PostgreSQL ---------------------------------------------------------------------------------

mod pg {
    use std::sync::atomic::{AtomicU32, Ordering};

    /// `RESECTA_TEST_PG`, or `None` after printing why the test is skipped (failing in CI).
    pub fn url() -> Option<String> {
        match std::env::var("RESECTA_TEST_PG") {
            Ok(url) if !url.is_empty() => Some(url),
            _ => {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "RESECTA_TEST_PG not set: CI must run the PostgreSQL tests \
                     (scripts/pg_cluster.sh start DIR)"
                );
                eprintln!("SKIPPED: RESECTA_TEST_PG not set");
                None
            }
        }
    }

    /// `url` without the parameters only PostgresStore knows (the admin connection is plain).
    fn plain(url: &str) -> String {
        let (base, query) = url.split_once('?').unwrap_or((url, ""));
        let kept: Vec<&str> = query
            .split('&')
            .filter(|p| {
                !p.is_empty() && !p.starts_with("sslmode=") && !p.starts_with("sslrootcert=")
            })
            .collect();
        if kept.is_empty() {
            base.to_owned()
        } else {
            format!("{base}?{}", kept.join("&"))
        }
    }

    /// `url` naming database `db` instead of its own.
    pub fn with_db(url: &str, db: &str) -> String {
        let (base, query) = url
            .split_once('?')
            .map_or((url, None), |(b, q)| (b, Some(q)));
        let scheme_end = base.find("://").map_or(0, |i| i + 3);
        let authority_end = base[scheme_end..]
            .find('/')
            .map_or(base.len(), |i| scheme_end + i);
        let mut out = format!("{}/{db}", &base[..authority_end]);
        if let Some(q) = query {
            out = format!("{out}?{q}");
        }
        out
    }

    /// `url` with `host` (and the same port) instead of its host.
    pub fn with_host(url: &str, host: &str) -> String {
        let scheme_end = url.find("://").unwrap() + 3;
        let at = url[scheme_end..]
            .find('@')
            .map_or(scheme_end, |i| scheme_end + i + 1);
        let colon = url[at..].find(':').map(|i| at + i).unwrap();
        format!("{}{host}{}", &url[..at], &url[colon..])
    }

    pub fn admin(url: &str) -> postgres::Client {
        postgres::Client::connect(&plain(url), postgres::NoTls).unwrap()
    }

    /// A fresh database, dropped (with any connection left to it) at the end of the test.
    pub struct Db {
        server: String,
        pub name: String,
        pub url: String,
    }

    impl Db {
        pub fn new() -> Option<Self> {
            Self::owned_by(None)
        }

        pub fn owned_by(owner: Option<&str>) -> Option<Self> {
            static N: AtomicU32 = AtomicU32::new(0);
            let server = url()?;
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .subsec_nanos();
            let name = format!(
                "resecta_t_{}_{}_{nanos}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            );
            let owner = owner.map_or(String::new(), |o| format!(" OWNER {o}"));
            admin(&server)
                .batch_execute(&format!(
                    "CREATE DATABASE {name} ENCODING 'UTF8' TEMPLATE template0{owner}"
                ))
                .unwrap();
            let url = with_db(&server, &name);
            Some(Self { server, name, url })
        }

        pub fn admin(&self) -> postgres::Client {
            admin(&self.url)
        }
    }

    impl Drop for Db {
        fn drop(&mut self) {
            let dropped = postgres::Client::connect(&plain(&self.server), postgres::NoTls)
                .and_then(|mut c| {
                    c.batch_execute(&format!(
                        "DROP DATABASE IF EXISTS {} WITH (FORCE)",
                        self.name
                    ))
                });
            if let Err(e) = dropped {
                eprintln!("could not drop test database {}: {e}", self.name);
            }
        }
    }
}

/// A server drops its store on a runtime thread at shutdown: the synchronous driver's
/// connections must not close on it (their close blocks on a runtime of their own).
#[test]
fn pg_store_dropped_on_an_async_runtime_thread() {
    let Some(db) = pg::Db::new() else { return };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap();
    let s = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap();
    s.create_session(&rec("r", 1)).unwrap();
    runtime.block_on(async move { drop(s) });
    let s = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap();
    assert_eq!(s.sessions().unwrap().len(), 1);
}

#[test]
fn pg_reopen_restores_everything() {
    let Some(db) = pg::Db::new() else { return };
    reopen_restores_everything(|| {
        PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap()
    });
}

/// Two pools on one database race appends to one session: every position is won once.
#[test]
fn pg_two_stores_race_appends() {
    let Some((a, b, _db)) = postgres_pair() else {
        return;
    };
    a.create_session(&rec("race", 1)).unwrap();
    const EACH: u64 = 30;
    let won: Vec<Vec<u64>> = std::thread::scope(|scope| {
        let handles: Vec<_> = [&a, &b, &a, &b]
            .into_iter()
            .enumerate()
            .map(|(t, s)| {
                scope.spawn(move || {
                    let mut positions = Vec::new();
                    while (positions.len() as u64) < EACH {
                        let len = s.log_len("race").unwrap();
                        match s.append("race", len, &[format!("t{t}")]) {
                            Ok(n) => positions.push(n),
                            Err(StoreError::Conflict { .. }) => {}
                            Err(e) => panic!("{e}"),
                        }
                    }
                    positions
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut all: Vec<u64> = won.concat();
    all.sort_unstable();
    assert_eq!(all, (1..=4 * EACH).collect::<Vec<_>>());
    assert_eq!(b.log("race", 0).unwrap().len() as u64, 4 * EACH);
}

#[test]
fn pg_newer_or_foreign_schema_is_refused() {
    let Some(db) = pg::Db::new() else { return };
    drop(PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap());
    // Opening again (migrating nothing) works; a newer version is refused.
    drop(PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap());
    db.admin()
        .batch_execute("UPDATE resecta_schema SET version = 99")
        .unwrap();
    let err = PostgresStore::open(&db.url, None, StoreOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::SchemaTooNew { found: 99, supported } if supported == PostgresStore::SCHEMA_VERSION
        ),
        "{err}"
    );
    assert!(err.to_string().contains("newer"), "{err}");

    let Some(foreign) = pg::Db::new() else { return };
    foreign
        .admin()
        .batch_execute("CREATE TABLE log (t text)")
        .unwrap();
    let err = PostgresStore::open(&foreign.url, None, StoreOptions::default()).unwrap_err();
    assert!(
        matches!(&err, StoreError::Corrupt { detail } if detail.contains("not a resecta store")),
        "{err}"
    );
}

/// Replicas opening a new database at once: one creates the schema, the others find it.
#[test]
fn pg_concurrent_opens_migrate_once() {
    let Some(db) = pg::Db::new() else { return };
    let stores: Vec<PostgresStore> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..4)
            .map(|_| scope.spawn(|| PostgresStore::open(&db.url, None, StoreOptions::default())))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap().unwrap())
            .collect()
    });
    stores[0].create_session(&rec("x", 1)).unwrap();
    assert_eq!(stores[3].sessions().unwrap().len(), 1);
    let versions: i64 = db
        .admin()
        .query_one("SELECT count(*) FROM resecta_schema", &[])
        .unwrap()
        .get(0);
    assert_eq!(versions, 1);
}

#[test]
fn pg_text_with_nul_is_invalid() {
    let Some((s, _db)) = postgres(StoreOptions::default()) else {
        return;
    };
    let mut r = rec("n", 1);
    r.display_name = "a\0b".into();
    assert!(matches!(
        s.create_session(&r),
        Err(StoreError::Invalid { .. })
    ));
    s.create_session(&rec("n", 1)).unwrap();
    let err = s.append("n", 0, &strings(["x\0y"])).unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::Invalid {
                what: "log record",
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(s.log_len("n").unwrap(), 0);
}

const PW_ROLE: &str = "resecta_pw";
const PW_RIGHT: &str = "correct-horse-battery";

#[test]
fn pg_wrong_password_is_named_not_echoed() {
    let Some(server) = pg::url() else { return };
    pg::admin(&server)
        .batch_execute(&format!(
            "DO $$ BEGIN
               IF NOT EXISTS (SELECT FROM pg_roles WHERE rolname = '{PW_ROLE}') THEN
                 CREATE ROLE {PW_ROLE} LOGIN;
               END IF;
             END $$;
             ALTER ROLE {PW_ROLE} PASSWORD '{PW_RIGHT}'"
        ))
        .unwrap();
    let Some(db) = pg::Db::owned_by(Some(PW_ROLE)) else {
        return;
    };
    let user_url = db.url.replacen("://", &format!("://{PW_ROLE}@"), 1);
    let user_url = match user_url.split_once('@') {
        // Drop the server URL's own user, if it named one.
        Some((head, rest)) if rest.contains('@') => {
            format!("{head}@{}", rest.split_once('@').unwrap().1)
        }
        _ => user_url,
    };
    let wrong = "Wr0ng-S3cret-Pa55word";
    // Given separately, and in the URL.
    let in_url = user_url.replacen(&format!("{PW_ROLE}@"), &format!("{PW_ROLE}:{wrong}@"), 1);
    for (url, pw) in [(&user_url, Some(wrong.to_owned())), (&in_url, None)] {
        match PostgresStore::open(url, pw, StoreOptions::default()) {
            Ok(_) => {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "the server took a wrong password for {PW_ROLE}: its pg_hba.conf must ask \
                     {PW_ROLE} for one (scripts/pg_cluster.sh does)"
                );
                eprintln!("SKIPPED: the server does not ask {PW_ROLE} for a password");
                return;
            }
            Err(err) => {
                let (msg, dbg) = (err.to_string(), format!("{err:?}"));
                assert!(msg.contains("password authentication failed"), "{msg}");
                assert!(msg.contains(&db.name), "names the database: {msg}");
                assert!(
                    !msg.contains(wrong) && !dbg.contains(wrong),
                    "{msg} / {dbg}"
                );
            }
        }
    }
    // The right one, given separately, overrides a wrong one in the URL.
    let s = PostgresStore::open(&in_url, Some(PW_RIGHT.into()), StoreOptions::default()).unwrap();
    s.create_session(&rec("ok", 1)).unwrap();
    let dbg = format!("{s:?}");
    assert!(!dbg.contains(PW_RIGHT) && !dbg.contains(wrong), "{dbg}");
    assert!(!s.target().contains(PW_RIGHT) && !s.target().contains(wrong));
}

/// A port nothing listens on.
fn closed_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

fn fixture_ca() -> String {
    format!("{}/tests/data/other-ca.pem", env!("CARGO_MANIFEST_DIR"))
}

/// Needs no server: what an unreachable database and bad TLS settings say.
#[test]
fn pg_unreachable_or_misconfigured_says_why_without_the_password() {
    let port = closed_port();
    let secret = "S3cret-In-The-Url";
    let url = format!(
        "postgres://alice:{secret}@127.0.0.1:{port}/plans?sslmode=verify-full&sslrootcert={}",
        fixture_ca()
    );
    let err = PostgresStore::open(&url, None, StoreOptions::default()).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, StoreError::Backend(_)), "{err:?}");
    assert!(
        msg.contains(&format!(
            "postgres://alice@127.0.0.1:{port}/plans (sslmode=verify-full)"
        )),
        "{msg}"
    );
    assert!(msg.contains("error connecting to server"), "{msg}");
    assert!(
        !msg.contains(secret) && !format!("{err:?}").contains(secret),
        "{msg}"
    );
    let err = PostgresStore::open(&url, Some("Other-Secret-1".into()), StoreOptions::default())
        .unwrap_err();
    assert!(!format!("{err} {err:?}").contains("Other-Secret-1"));

    let bad = |url: &str, want: &str| {
        let err = PostgresStore::open(url, None, StoreOptions::default()).unwrap_err();
        assert!(matches!(err, StoreError::Invalid { .. }), "{err:?}");
        assert!(err.to_string().contains(want), "{err}");
        assert!(!err.to_string().contains(secret), "{err}");
    };
    let base = format!("postgres://alice:{secret}@127.0.0.1:{port}/plans");
    bad(&format!("{base}?sslmode=verify-full"), "needs sslrootcert");
    bad(&format!("{base}?sslmode=verify-ca"), "needs sslrootcert");
    bad(&format!("{base}?sslmode=sometimes"), "sslmode");
    bad(
        &format!("{base}?sslmode=require&sslrootcert=/nonexistent.pem"),
        "/nonexistent.pem",
    );
    bad(&format!("{base}?nonsense=1"), "nonsense");
    bad("host=localhost user=alice", "postgres://");
}

/// TLS against pg_cluster.sh's server, whose certificate (by RESECTA_TEST_PG_CA) names
/// "localhost" only.
#[test]
fn pg_tls_modes() {
    let Some(db) = pg::Db::new() else { return };
    let Some(ca) = std::env::var("RESECTA_TEST_PG_CA")
        .ok()
        .filter(|c| !c.is_empty())
    else {
        eprintln!("SKIPPED: RESECTA_TEST_PG_CA not set");
        return;
    };
    let url = |host: &str, params: &str| {
        let u = pg::with_host(&db.url, host);
        let sep = if u.contains('?') { '&' } else { '?' };
        format!("{u}{sep}{params}")
    };
    let open = |url: String| PostgresStore::open(&url, None, StoreOptions::default());
    let encrypted = |url: String| open(url).unwrap().encrypted().unwrap();
    assert!(!encrypted(url("127.0.0.1", "sslmode=disable")));
    assert!(encrypted(url("127.0.0.1", "sslmode=prefer")));
    assert!(encrypted(url("127.0.0.1", "sslmode=require")));
    // The chain is good; the name 127.0.0.1 is not in the certificate.
    assert!(encrypted(url(
        "127.0.0.1",
        &format!("sslmode=verify-ca&sslrootcert={ca}")
    )));
    assert!(encrypted(url(
        "localhost",
        &format!("sslmode=verify-full&sslrootcert={ca}")
    )));
    let s = open(url(
        "localhost",
        &format!("sslmode=verify-full&sslrootcert={ca}"),
    ))
    .unwrap();
    s.create_session(&rec("tls", 1)).unwrap();
    assert_eq!(s.append("tls", 0, &strings(["x"])).unwrap(), 1);
    let err = open(url(
        "127.0.0.1",
        &format!("sslmode=verify-full&sslrootcert={ca}"),
    ))
    .unwrap_err();
    assert!(err.to_string().contains("TLS"), "{err}");
    assert!(err.to_string().contains("not valid for name"), "{err}");
    // Another CA: the chain does not verify, whatever the mode that checks it.
    let other = fixture_ca();
    for mode in ["verify-full", "verify-ca", "require"] {
        let err = open(url(
            "localhost",
            &format!("sslmode={mode}&sslrootcert={other}"),
        ))
        .unwrap_err();
        assert!(err.to_string().contains("UnknownIssuer"), "{mode}: {err}");
    }
}
