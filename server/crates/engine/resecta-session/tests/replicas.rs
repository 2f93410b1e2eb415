#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Session ownership across replicas sharing one store (two `Service`s over two handles of one
//! `MemoryStore`): one holder at a time, calls elsewhere answered with the holder's address,
//! take-over from the log once the lease ends, and a superseded holder's writes fenced.

mod common;

use std::sync::Arc;
use std::time::Duration;

use common::{config, init_op, loaded_session};
use resecta_plan::PlanEvent;
use resecta_session::api::EditOp;
use resecta_session::{ErrorKind, ReplicaConfig, Service, SessionError};
use resecta_store::{MemoryStore, Replica, StoreOptions};

const LEASE: Duration = Duration::from_millis(300);

fn replica(name: &str, store: MemoryStore) -> Arc<Service> {
    let mut c = config();
    c.replica = Some(ReplicaConfig {
        replica: Replica {
            id: name.into(),
            grpc: format!("{name}.local:50051"),
            http: format!("http://{name}.local:8080"),
        },
        lease: LEASE,
    });
    Arc::new(Service::new(Arc::new(store), c))
}

fn drag(x: f64) -> EditOp {
    EditOp::Event {
        event: PlanEvent::SetControlPoint {
            name: "r1".into(),
            i: 1,
            j: 2,
            point: [x, 4.0, 3.0],
        },
    }
}

/// The holder named by an `Elsewhere` error.
fn holder(e: &SessionError) -> String {
    assert_eq!(e.kind(), ErrorKind::Elsewhere, "{e}");
    assert_eq!(e.code(), "SESSION_ELSEWHERE");
    let SessionError::Elsewhere(Some(at)) = e else {
        panic!("no address in {e}");
    };
    at.id.clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_holder_at_a_time_take_over_from_the_log_and_fencing() {
    let shared = MemoryStore::new(StoreOptions::default());
    let a = replica("a", shared.share());
    let b = replica("b", shared.share());
    let id = loaded_session(&a, "Replicated").await;
    a.edit(&id, 0, init_op()).await.unwrap();
    let acked = a.edit(&id, 0, drag(-6.0)).await.unwrap().plan_version;
    let mut watcher = a.watch(&id, None).await.unwrap();

    // While A's lease runs, B answers with A's address and changes nothing.
    let e = b.edit(&id, 0, drag(-9.0)).await.unwrap_err();
    assert_eq!(holder(&e), "a");
    assert!(e.to_string().contains("a.local:50051"), "{e}");
    let e = b.get_session(&id).await.unwrap_err();
    assert_eq!(holder(&e), "a");
    // Listing is not a session call: every replica lists every session.
    assert_eq!(b.list_sessions().await.unwrap().len(), 1);

    // A stops renewing (paused, or dead): B takes the session over from the log.
    tokio::time::sleep(LEASE + Duration::from_millis(100)).await;
    let info = b.get_session(&id).await.unwrap();
    assert_eq!(info.plan_version, acked, "every acknowledged edit is there");
    let plan_b = b.export_plan(&id).await.unwrap().value;
    let after = b.edit(&id, acked, drag(-7.0)).await.unwrap().plan_version;
    assert_eq!(after, acked + 1);
    let plan_after = b.export_plan(&id).await.unwrap().value;
    assert_ne!(plan_after, plan_b);

    // A wakes up still holding the session in memory: its late write is fenced, it drops the
    // session and names B; the log is unchanged.
    let e = a.edit(&id, acked, drag(-20.0)).await.unwrap_err();
    assert_eq!(holder(&e), "b");
    assert_eq!(b.export_plan(&id).await.unwrap().value, plan_after);
    assert_eq!(b.get_session(&id).await.unwrap().plan_version, after);
    // A's watcher was told where the session went.
    loop {
        match tokio::time::timeout(Duration::from_secs(10), watcher.next())
            .await
            .expect("the stream ends in time")
        {
            Some(Ok(_)) => {}
            Some(Err(e)) => {
                assert_eq!(holder(&e), "b");
                break;
            }
            None => panic!("the stream ended without saying where the session went"),
        }
    }
    // And A's next call for it is redirected without touching the log.
    let e = a.get_session(&id).await.unwrap_err();
    assert_eq!(holder(&e), "b");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn renewal_keeps_a_session_and_draining_hands_it_over_at_once() {
    let shared = MemoryStore::new(StoreOptions::default());
    let a = replica("a", shared.share());
    let b = replica("b", shared.share());
    let id = loaded_session(&a, "Drained").await;
    a.edit(&id, 0, init_op()).await.unwrap();
    // Renewed every third of the lease, for three leases: still A's.
    for _ in 0..9 {
        tokio::time::sleep(LEASE / 3).await;
        assert_eq!(a.renew_leases().await.unwrap(), 0);
    }
    assert_eq!(holder(&b.get_session(&id).await.unwrap_err()), "a");
    // Draining releases the lease: B's next call takes the session without waiting.
    assert_eq!(a.release_leases().await.unwrap(), 1);
    let info = b.get_session(&id).await.unwrap();
    assert_eq!(info.plan_version, 2);
    // A has let it go: renewing finds nothing, and its next call is redirected to B.
    assert_eq!(a.renew_leases().await.unwrap(), 0);
    assert_eq!(holder(&a.get_session(&id).await.unwrap_err()), "b");
    // B loses it when its lease is taken over while it does not renew.
    tokio::time::sleep(LEASE + Duration::from_millis(100)).await;
    a.get_session(&id).await.unwrap();
    assert_eq!(b.renew_leases().await.unwrap(), 1);
    assert_eq!(holder(&b.get_session(&id).await.unwrap_err()), "a");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_spread_over_replicas_and_deletion_needs_the_holder() {
    let shared = MemoryStore::new(StoreOptions::default());
    let a = replica("a", shared.share());
    let b = replica("b", shared.share());
    let mut ids = Vec::new();
    for k in 0..10 {
        let r = if k % 2 == 0 { &a } else { &b };
        ids.push(r.create_session("Spread").await.unwrap().id);
    }
    for (k, id) in ids.iter().enumerate() {
        let (mine, other, other_name) = if k % 2 == 0 {
            (&a, &b, "a")
        } else {
            (&b, &a, "b")
        };
        mine.get_session(id).await.unwrap();
        assert_eq!(
            holder(&other.get_session(id).await.unwrap_err()),
            other_name
        );
        assert_eq!(
            holder(&other.delete_session(id).await.unwrap_err()),
            other_name
        );
    }
    a.delete_session(&ids[0]).await.unwrap();
    assert_eq!(b.list_sessions().await.unwrap().len(), 9);
    let e = b.get_session(&ids[0]).await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::NotFound);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_replica_takes_its_sessions_back_at_once() {
    let shared = MemoryStore::new(StoreOptions::default());
    let first = replica("a@1", shared.share());
    let id = loaded_session(&first, "Restarted").await;
    first.edit(&id, 0, init_op()).await.unwrap();
    let other = replica("b@1", shared.share());
    assert_eq!(holder(&other.get_session(&id).await.unwrap_err()), "a@1");
    // The same name in a new process (the old one crashed): no wait for the lease.
    let second = replica("a@2", shared.share());
    assert_eq!(second.get_session(&id).await.unwrap().plan_version, 2);
    // Had the first process only paused, its writes are fenced now.
    assert_eq!(
        holder(&first.edit(&id, 2, drag(-8.0)).await.unwrap_err()),
        "a@2"
    );
    assert_eq!(second.get_session(&id).await.unwrap().plan_version, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_session_quota_is_the_shared_stores() {
    let shared = MemoryStore::new(StoreOptions::default());
    let quota = |name: &str| {
        let s = replica(name, shared.share());
        let mut c = s.config().clone();
        c.max_sessions = 4;
        Arc::new(Service::new(Arc::new(shared.share()), c))
    };
    let (a, b) = (quota("a"), quota("b"));
    for k in 0..4 {
        let r = if k % 2 == 0 { &a } else { &b };
        r.create_session("Quota").await.unwrap();
    }
    for r in [&a, &b] {
        let e = r.create_session("Over").await.unwrap_err();
        assert_eq!(e.code(), "SESSION_QUOTA", "{e}");
    }
}
