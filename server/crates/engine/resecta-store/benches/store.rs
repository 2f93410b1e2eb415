#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Append of one ~300-byte edit record (fsync included on SQLite) and put/get of a 512×512×300 u8
//! label map (78.6 MB, one ellipsoid label) at zstd levels 1 and 3, on SQLite and memory; the
//! append also on PostgreSQL when `RESECTA_TEST_PG` names a database the store may use (its
//! tables are created there if missing; the bench's session is `bench-append-<pid>`).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use resecta_store::{
    Blob, MemoryStore, PostgresStore, SessionRecord, SessionStore, SqliteStore, StoreOptions,
};

fn session(id: &str) -> SessionRecord {
    SessionRecord {
        id: id.to_owned(),
        display_name: "bench".into(),
        created_ms: 0,
        last_access_ms: 0,
    }
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

/// A translate edit as the plan's event JSON would carry it (~300 bytes).
fn edit_record(seq: u64) -> String {
    let r = format!(
        r#"{{"type":"move_points","version":{seq},"indices":[[3,4],[3,5],[4,4],[4,5]],"delta_mm":[1.25,-0.5,2.0],"client":"slicer-7f3a","at_ms":1718000000000,"margin_mm":10.0,"band_mm":5.0,"resolution":[40,40],"note":"drag group"}}"#
    );
    debug_assert!((250..350).contains(&r.len()));
    r
}

fn bench_append(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let sqlite = SqliteStore::open(dir.path(), StoreOptions::default()).unwrap();
    let memory = MemoryStore::new(StoreOptions::default());
    let pg = std::env::var("RESECTA_TEST_PG")
        .ok()
        .filter(|u| !u.is_empty())
        .map(|url| PostgresStore::open(&url, None, StoreOptions::default()).unwrap());
    let mut stores: Vec<(&str, &dyn SessionStore)> = vec![("sqlite", &sqlite), ("memory", &memory)];
    if let Some(pg) = &pg {
        stores.push(("postgres", pg));
    }
    let id = format!("bench-append-{}", std::process::id());
    let mut group = c.benchmark_group("append_one_300B");
    group.throughput(Throughput::Elements(1));
    for (name, store) in stores {
        store.create_session(&session(&id)).unwrap();
        let mut len = 0;
        group.bench_function(BenchmarkId::from_parameter(name), |b| {
            b.iter(|| len = store.append(&id, len, &[edit_record(len + 1)]).unwrap())
        });
        if name == "postgres" {
            store.delete_session(&id).unwrap();
        }
    }
    group.finish();
}

fn bench_label_map(c: &mut Criterion) {
    let map = Blob {
        meta_json: r#"{"dims":[512,512,300],"type":"u8"}"#.into(),
        data: label_map(512, 512, 300),
    };
    let mut group = c.benchmark_group("labelmap_512x512x300_u8");
    group.throughput(Throughput::Bytes(map.data.len() as u64));
    group.sample_size(10);
    for level in [1, 3] {
        let opts = StoreOptions {
            zstd_level: level,
            ..StoreOptions::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let sqlite = SqliteStore::open(dir.path(), opts).unwrap();
        let memory = MemoryStore::new(opts);
        let stores: [(&str, &dyn SessionStore); 2] = [("sqlite", &sqlite), ("memory", &memory)];
        for (name, store) in stores {
            store.create_session(&session("s")).unwrap();
            group.bench_function(BenchmarkId::new(format!("put/{name}"), level), |b| {
                b.iter(|| store.put_blob("s", "labelmap", &map).unwrap())
            });
            let stored = store.usage().unwrap().stored_bytes;
            eprintln!("level {level}: 78.6 MB label map stored in {stored} bytes ({name})");
            group.bench_function(BenchmarkId::new(format!("get/{name}"), level), |b| {
                b.iter(|| store.blob("s", "labelmap").unwrap().unwrap())
            });
            assert_eq!(store.blob("s", "labelmap").unwrap().unwrap(), map);
        }
    }
    group.finish();
}

criterion_group!(benches, bench_append, bench_label_map);
criterion_main!(benches);
