//! A watchdog for a rank that is stopped (SIGSTOP, `kill -STOP`, a terminal's job control on
//! one process): without it the other ranks wait for it in their next collective forever,
//! busy-polling a core each (OpenMPI's default progress).
//!
//! **What it watches.** At start-up every rank learns each rank's host and process id (one
//! all-gather on the world communicator, before the job's own work). Each rank then runs one
//! thread that, once a second, reads the state of every *other rank on its own host* from
//! `/proc/<pid>/stat`. A peer continuously in state `T` (stopped by a signal) for the limit
//! ends the job: the watching rank prints one line naming the stopped rank, its pid and host,
//! and leaves with exit code 1 (`_exit`); mpirun then ends every rank of the job, the stopped
//! one included. A rank held by a debugger (state `t`, tracing stop) is not counted, so
//! attaching gdb to one rank stays possible.
//!
//! **Why this and not a heartbeat.** The thread makes no MPI call: the runtime is initialised
//! with `MPI_Init` (`MPI_THREAD_SINGLE`), and a heartbeat exchanged by a second thread would
//! need `MPI_THREAD_MULTIPLE`, which puts a lock around every MPI call of the solver. A limit
//! on the time spent in a collective cannot be kept either: the long collectives are inside
//! PETSc and SLEPc (a shift-and-invert solve of a large mesh is one of them for minutes), and
//! a slow rank is no stopped one. Reading `/proc` costs nothing the solver would notice.
//!
//! **Pauses of the whole job.** The stopped time is summed over polls whose interval is
//! regular; a gap much longer than the poll (this rank was itself stopped, as when the whole
//! job is paused with `kill -STOP` and resumed with `kill -CONT`) starts the count again, so
//! resuming the ranks one after the other never ends the job.
//!
//! **Limits.** Ranks on another host are not watched (their `/proc` is not visible): for
//! multi-host runs, and for a rank that hangs while running (a deadlock, a file system that
//! never answers), a wall-clock limit on the whole job is the remedy (`mpirun --timeout SECS`,
//! or the batch system's time limit). A rank stopped during start-up, before the all-gather,
//! is not caught either.
//!
//! The limit is `--rank-timeout SECS` (any command), else the environment variable
//! `DIFFSOUND_RANK_TIMEOUT`, else [`DEFAULT_LIMIT_SECONDS`]; 0 turns the watchdog off.

use std::time::{Duration, Instant};

/// Seconds a rank may stay stopped before the job ends, unless told otherwise.
pub const DEFAULT_LIMIT_SECONDS: f64 = 600.0;

/// The environment variable read when `--rank-timeout` is not given.
pub const ENV_VAR: &str = "DIFFSOUND_RANK_TIMEOUT";

/// A limit that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum LimitError {
    #[error("{ENV_VAR}={text:?} is not a number of seconds (0 turns the rank watchdog off)")]
    NotANumber { text: String },
    #[error("--rank-timeout must be a number of seconds ≥ 0 (0: off), got {seconds}")]
    OutOfRange { seconds: f64 },
}

/// The limit from the flag, else the environment, else the default; `None`: off.
pub fn limit(flag: Option<f64>) -> Result<Option<Duration>, LimitError> {
    let seconds = match flag {
        Some(s) => s,
        None => match std::env::var(ENV_VAR) {
            Ok(text) => text
                .trim()
                .parse::<f64>()
                .map_err(|_| LimitError::NotANumber { text: text.clone() })?,
            Err(_) => DEFAULT_LIMIT_SECONDS,
        },
    };
    if !(seconds.is_finite() && seconds >= 0.0) {
        return Err(LimitError::OutOfRange { seconds });
    }
    Ok((seconds > 0.0).then(|| Duration::from_secs_f64(seconds)))
}

/// One other rank on this host.
#[derive(Clone, Copy, Debug)]
struct Peer {
    rank: usize,
    pid: u32,
}

/// FNV-1a of the text: the same on every rank, unlike std's randomly keyed hashers.
fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Which process table this process sees: the boot (one per host and boot) and the pid
/// namespace (one per container), so two ranks with equal keys see each other's `/proc`.
fn process_table_key() -> u64 {
    let boot = std::fs::read_to_string("/proc/sys/kernel/random/boot_id").unwrap_or_default();
    let ns = std::fs::read_link("/proc/self/ns/pid")
        .map(|p| p.display().to_string())
        .unwrap_or_default();
    if boot.is_empty() || ns.is_empty() {
        // No way to tell: this rank watches nobody (0 is never a peer's key, see `start`).
        return 0;
    }
    fnv1a(&format!("{}|{ns}", boot.trim())).max(1)
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "this host".into())
}

/// The state letter of process `pid` (`R`, `S`, `T`, `t`, …) and its start time (clock ticks
/// after boot, which tells a reused pid from the rank), `None` if it is gone.
fn process_state(pid: u32) -> Option<(char, u64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // "pid (comm) S ppid … starttime …": the command may hold spaces and parentheses, so the
    // fields are counted after the last ')'; the state is field 3, the start time field 22.
    let mut fields = stat.rsplit_once(')')?.1.split_whitespace();
    let state = fields.next()?.chars().next()?;
    let start = fields.nth(18)?.parse().ok()?;
    Some((state, start))
}

/// Learns the ranks on this host (collective: every rank of `world` calls it) and, with a
/// limit, starts the watching thread (module docs).
pub fn start<C: mpi::topology::Communicator>(world: &C, limit: Option<Duration>) {
    use mpi::collective::CommunicatorCollectives;
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    if size < 2 {
        return;
    }
    // Every rank takes part, with or without a limit of its own, so the collective matches.
    let mine = [process_table_key(), u64::from(std::process::id())];
    let mut all = vec![0u64; 2 * size];
    world.all_gather_into(&mine[..], &mut all[..]);
    let Some(limit) = limit else { return };
    if mine[0] == 0 {
        return;
    }
    let peers: Vec<Peer> = all
        .chunks_exact(2)
        .enumerate()
        .filter(|&(r, kp)| r != rank && kp[0] == mine[0])
        .map(|(r, kp)| Peer {
            rank: r,
            pid: kp[1] as u32,
        })
        .collect();
    if peers.is_empty() {
        return;
    }
    let _ = std::thread::Builder::new()
        .name("rank-watchdog".into())
        .spawn(move || watch(rank, size, peers, limit));
}

/// The watching loop (module docs); returns never, or when the thread cannot go on.
fn watch(rank: usize, size: usize, peers: Vec<Peer>, limit: Duration) {
    let poll = Duration::from_secs(1)
        .min(limit / 4)
        .max(Duration::from_millis(50));
    // A gap this long between polls means this rank was itself paused: the count restarts.
    let pause = 3 * poll + Duration::from_secs(1);
    let mut stopped = vec![Duration::ZERO; peers.len()];
    // Each peer's start time when first seen; a pid that later shows another is no rank.
    let mut started: Vec<Option<u64>> = peers
        .iter()
        .map(|p| process_state(p.pid).map(|s| s.1))
        .collect();
    let mut last = Instant::now();
    loop {
        std::thread::sleep(poll);
        let now = Instant::now();
        let gap = now - last;
        last = now;
        if gap > pause {
            stopped.iter_mut().for_each(|s| *s = Duration::ZERO);
            continue;
        }
        for (k, peer) in peers.iter().enumerate() {
            match (process_state(peer.pid), started[k]) {
                (Some((state, start)), Some(first)) if start == first => {
                    if state == 'T' {
                        stopped[k] += gap;
                    } else {
                        stopped[k] = Duration::ZERO;
                    }
                }
                (Some((_, start)), None) => {
                    started[k] = Some(start);
                    stopped[k] = Duration::ZERO;
                }
                _ => stopped[k] = Duration::ZERO,
            }
        }
        let Some(k) = (0..peers.len()).find(|&k| stopped[k] >= limit) else {
            continue;
        };
        // The lowest running rank on the host speaks; any other waits for mpirun to end it.
        let lower_running = peers
            .iter()
            .zip(&stopped)
            .any(|(p, s)| p.rank < rank && s.is_zero() && process_state(p.pid).is_some());
        if lower_running {
            std::thread::sleep(Duration::from_secs(5));
        }
        let peer = peers[k];
        eprintln!(
            "error (rank {rank} of {size}): rank {} (pid {} on {}) has been stopped for {:.0} s (SIGSTOP) and the job cannot go on without it; ending the job (resume a paused rank in time with `kill -CONT {}`; --rank-timeout SECS or {ENV_VAR} sets the limit, 0 turns this off)",
            peer.rank,
            peer.pid,
            host_name(),
            stopped[k].as_secs_f64(),
            peer.pid
        );
        // No MPI call from this thread (module docs): leave at once with a failure; mpirun
        // sees a rank end without finalising and ends the others.
        // SAFETY: _exit ends the process without running handlers that could need the main
        // thread's locks.
        unsafe { libc::_exit(1) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_comes_from_the_flag_then_the_default_and_zero_is_off() {
        assert_eq!(limit(Some(0.0)).unwrap(), None);
        assert_eq!(limit(Some(2.5)).unwrap(), Some(Duration::from_millis(2500)));
        assert!(limit(Some(-1.0)).is_err());
        assert!(limit(Some(f64::NAN)).is_err());
    }

    #[test]
    fn a_stopped_child_shows_state_t_and_a_running_one_does_not() {
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        let pid = child.id();
        let state = || process_state(pid).map(|s| s.0);
        let (_, start) = process_state(pid).unwrap();
        assert_ne!(state(), Some('T'));
        // SAFETY: signalling our own child.
        unsafe { libc::kill(pid as i32, libc::SIGSTOP) };
        let t = Instant::now();
        while state() != Some('T') && t.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(process_state(pid), Some(('T', start)));
        child.kill().unwrap();
        child.wait().unwrap();
        assert_eq!(state(), None);
    }

    #[test]
    fn the_process_table_key_is_stable_and_set() {
        let k = process_table_key();
        assert_ne!(k, 0);
        assert_eq!(k, process_table_key());
    }
}
