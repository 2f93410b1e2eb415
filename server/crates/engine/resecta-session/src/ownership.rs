//! Session ownership on a replicated server (several `resecta serve` sharing one store,
//! docs/deployment.md): a replica holds a session only under its lease in the store, claimed
//! when a call first names the session and renewed while the replica lives; a call for a
//! session another replica holds is answered with [`SessionError::Elsewhere`] and that
//! replica's address. A replica whose lease ended (it paused past the lease, or the store
//! fenced one of its writes) drops the session: its watchers are told where it went, and its
//! next call claims the session anew (restoring it from the log). Draining releases every
//! lease so that others take the sessions over at once. Without a [`ReplicaConfig`] every
//! method here does nothing.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use resecta_store::{Claim, Lease, StoreError};

use crate::api::ReplicaAddress;
use crate::config::ReplicaConfig;
use crate::error::{Result, SessionError};
use crate::service::Service;
use crate::support::blocking;

fn address(lease: Lease) -> ReplicaAddress {
    ReplicaAddress {
        id: lease.holder.id,
        grpc: lease.holder.grpc,
        http: lease.holder.http,
        lease_remaining_ms: lease.remaining_ms,
    }
}

fn lease_ms(r: &ReplicaConfig) -> u64 {
    u64::try_from(r.lease.as_millis()).unwrap_or(u64::MAX)
}

impl Service {
    /// This replica, on a replicated server.
    pub fn replica(&self) -> Option<&ReplicaConfig> {
        self.config.replica.as_ref()
    }

    /// Claims the lease on session `id` for this replica.
    pub(crate) async fn claim(&self, id: &str) -> Result<()> {
        let Some(r) = self.config.replica.clone() else {
            return Ok(());
        };
        let store = Arc::clone(&self.store);
        let key = id.to_owned();
        let claim = blocking(move || Ok(store.claim(&key, &r.replica, lease_ms(&r))?)).await?;
        match claim {
            Claim::Granted { .. } => Ok(()),
            Claim::Held(lease) => Err(SessionError::Elsewhere(Some(address(lease)))),
        }
    }

    /// Where session `id` went, if another replica holds it now.
    async fn holder(&self, id: &str) -> Option<ReplicaAddress> {
        let store = Arc::clone(&self.store);
        let key = id.to_owned();
        let mine = self.config.replica.as_ref()?.replica.id.clone();
        match blocking(move || Ok(store.lease(&key)?)).await {
            Ok(Some(lease)) if lease.holder.id != mine => Some(address(lease)),
            Ok(_) | Err(_) => None,
        }
    }

    /// Stops holding session `id` (its lease ended): frees its memory, stops its planner
    /// set-up and ends its watch streams with `Elsewhere(at)`.
    pub(crate) fn evict(&self, id: &str, at: Option<ReplicaAddress>) -> Result<()> {
        if let Some(s) = self.registry.remove(id)? {
            s.lost.store(true, Ordering::Release);
            s.deleted.store(true, Ordering::Release);
            s.hub.close_moved(at);
            self.budget.release(id)?;
            tracing::info!(session = %id, "session dropped: another replica takes it");
        }
        Ok(())
    }

    /// A write of session `id` was fenced (another replica claimed it): drops it here and
    /// says where it went.
    pub(crate) async fn fenced(&self, id: &str) -> SessionError {
        let at = self.holder(id).await;
        if let Err(e) = self.evict(id, at.clone()) {
            return e;
        }
        SessionError::Elsewhere(at)
    }

    /// `e`, or, when it is a fenced write of session `id`, [`Self::fenced`]'s answer.
    pub(crate) async fn store_failed(&self, id: &str, e: SessionError) -> SessionError {
        if matches!(e, SessionError::Store(StoreError::Fenced { .. })) {
            self.fenced(id).await
        } else {
            e
        }
    }

    /// Renews the leases of every session held; drops those lost. Returns how many were lost.
    pub async fn renew_leases(&self) -> Result<usize> {
        let Some(r) = self.config.replica.clone() else {
            return Ok(0);
        };
        let ids = self.registry.ids()?;
        if ids.is_empty() {
            return Ok(0);
        }
        let store = Arc::clone(&self.store);
        let lost = blocking(move || Ok(store.renew(&r.replica.id, &ids, lease_ms(&r))?)).await?;
        for id in &lost {
            let at = self.holder(id).await;
            self.evict(id, at)?;
        }
        Ok(lost.len())
    }

    /// Releases every lease held (draining before a stop), so other replicas take the
    /// sessions over at their next call. Returns how many were released.
    pub async fn release_leases(&self) -> Result<usize> {
        let Some(r) = self.config.replica.clone() else {
            return Ok(0);
        };
        let mut n = 0;
        for id in self.registry.ids()? {
            self.evict(&id, None)?;
            let store = Arc::clone(&self.store);
            let mine = r.replica.id.clone();
            if blocking(move || Ok(store.release(&id, &mine)?)).await? {
                n += 1;
            }
        }
        Ok(n)
    }
}
