//! Collectives that carry a failure to every rank.
//!
//! A collective that one rank leaves early — because its own part of the work failed and it
//! returned its error — leaves the others waiting in the next broadcast or reduction for ever:
//! an MPI job that hangs instead of stopping with a message. Wherever one rank (or each rank on
//! its own share) computes something the others then wait for, the outcome goes first, so that
//! every rank returns the same `Ok` or the same `Err`:
//!
//! * [`share_from_root`]: rank 0 alone computes numbers of a length every rank knows; a status
//!   (0, or the length of rank 0's error message) is broadcast before the numbers or the message.
//! * [`agree`]: every rank computes its own part; one reduction finds the lowest rank that
//!   failed, and that rank's message is broadcast to all.
//!
//! And one that only waits: [`quiet_barrier`], for ranks idle while one rank works alone on
//! threads.

use super::Petsc;
use mpi::collective::SystemOperation;
use mpi::traits::{Communicator, CommunicatorCollectives, Root};

/// A barrier that waits asleep: the request is tested every millisecond instead of being
/// waited on (Open MPI's blocking calls poll, holding a core at 100 % while one rank works
/// alone, e.g. rank 0's catalogue, which then runs threads on those cores).
pub fn quiet_barrier(petsc: &Petsc) {
    if petsc.size() == 1 {
        return;
    }
    let mut request = petsc.world().immediate_barrier();
    loop {
        match request.test() {
            Ok(_) => return,
            Err(pending) => {
                request = pending;
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        }
    }
}

/// Broadcasts `data` from rank 0 in place (every rank passes a slice of the same length).
pub fn broadcast_slice(petsc: &Petsc, data: &mut [f64]) {
    if petsc.size() > 1 {
        petsc.world().process_at_rank(0).broadcast_into(data);
    }
}

/// Every rank's `local` (the same length on every rank), concatenated in rank order, on every
/// rank.
pub fn all_gather(petsc: &Petsc, local: &[f64]) -> Vec<f64> {
    if petsc.size() == 1 {
        return local.to_vec();
    }
    let mut out = vec![0.0; local.len() * petsc.size()];
    petsc.world().all_gather_into(local, &mut out[..]);
    out
}

/// Every rank's `local`, concatenated in rank order, on every rank; `counts[p]` is rank p's
/// length, known to every rank.
pub fn all_gather_varcount(petsc: &Petsc, local: &[f64], counts: &[usize]) -> Vec<f64> {
    assert_eq!(counts.len(), petsc.size(), "one count per rank");
    assert_eq!(local.len(), counts[petsc.rank()], "this rank's count");
    if petsc.size() == 1 {
        return local.to_vec();
    }
    let total: usize = counts.iter().sum();
    let mut out = vec![0.0; total];
    let counts_c: Vec<mpi::Count> = counts.iter().map(|&c| c as mpi::Count).collect();
    let displs: Vec<mpi::Count> = counts
        .iter()
        .scan(0usize, |at, &c| {
            let d = *at;
            *at += c;
            Some(d as mpi::Count)
        })
        .collect();
    let mut partition = mpi::datatype::PartitionMut::new(&mut out[..], counts_c, &displs[..]);
    petsc
        .world()
        .all_gather_varcount_into(local, &mut partition);
    out
}

/// Rank 0's result, on every rank. Rank 0 passes `Some(result)`, the others `None` (what they
/// pass is ignored); `len` is the length of an `Ok` vector, the same on every rank. A rank-0
/// `Ok` of another length is an error on every rank.
pub fn share_from_root(
    petsc: &Petsc,
    root_result: Option<Result<Vec<f64>, String>>,
    len: usize,
) -> Result<Vec<f64>, String> {
    let root_result = if petsc.rank() == 0 {
        match root_result {
            Some(Ok(v)) if v.len() != len => Err(format!(
                "rank 0 computed {} numbers where {len} were expected",
                v.len()
            )),
            Some(r) => r,
            None => Err("rank 0 passed no result to share".into()),
        }
    } else {
        Ok(Vec::new())
    };
    if petsc.size() == 1 {
        return root_result;
    }
    let root = petsc.world().process_at_rank(0);
    // 0: the numbers follow; n > 0: an error message of n bytes follows.
    let mut status: u64 = match &root_result {
        Err(message) if petsc.rank() == 0 => message.len().max(1) as u64,
        _ => 0,
    };
    root.broadcast_into(&mut status);
    if status == 0 {
        let mut data = match root_result {
            Ok(v) if petsc.rank() == 0 => v,
            _ => vec![0.0; len],
        };
        root.broadcast_into(&mut data[..]);
        Ok(data)
    } else {
        let mut bytes = match &root_result {
            Err(message) if petsc.rank() == 0 => message.clone().into_bytes(),
            _ => vec![0u8; status as usize],
        };
        // An empty message was sent as one space (status 0 means "numbers").
        bytes.resize(status as usize, b' ');
        root.broadcast_into(&mut bytes[..]);
        let message = String::from_utf8_lossy(&bytes).into_owned();
        Err(if petsc.rank() == 0 {
            message
        } else {
            format!("rank 0: {message}")
        })
    }
}

/// Every rank's own result, agreed on: `Ok` on every rank if every rank succeeded, else the same
/// error on every rank (the lowest failing rank's message, named by its rank). Collective.
pub fn agree<T>(petsc: &Petsc, local: Result<T, String>) -> Result<T, String> {
    if petsc.size() == 1 {
        return local;
    }
    let size = petsc.size() as u64;
    let mine: u64 = if local.is_err() {
        petsc.rank() as u64
    } else {
        size
    };
    let mut first_failed: u64 = size;
    petsc
        .world()
        .all_reduce_into(&mine, &mut first_failed, SystemOperation::min());
    if first_failed == size {
        return local;
    }
    let root = petsc.world().process_at_rank(first_failed as i32);
    let own = match &local {
        Err(message) if petsc.rank() as u64 == first_failed => Some(message.clone()),
        _ => None,
    };
    let mut len: u64 = own.as_ref().map_or(0, |m| m.len() as u64);
    root.broadcast_into(&mut len);
    let mut bytes = own.map_or_else(|| vec![0u8; len as usize], String::into_bytes);
    root.broadcast_into(&mut bytes[..]);
    Err(format!(
        "rank {first_failed}: {}",
        String::from_utf8_lossy(&bytes)
    ))
}
