//! How many worker threads a user may ask for (`--threads` of `lpm solve` and `lpm reference`).
//!
//! A count far above the machine's cores only costs: each thread of the CPU backend's pool sweeps
//! a share of every plane, so 512 threads on 2 cores made a 16³ solve 40 times slower, and
//! 100,000 never finished starting (issue 57). A count is taken up to [`OVERSUBSCRIPTION`] times
//! the cores (a little oversubscription can hide I/O waits; the results are bitwise the same at
//! any count), and refused beyond with an error saying the limit.

/// How many threads per core a user may ask for at most.
pub const OVERSUBSCRIPTION: usize = 4;

/// A thread count over the limit of this machine.
#[derive(Debug, thiserror::Error)]
#[error("--threads {requested}: at most {limit} on this machine ({OVERSUBSCRIPTION} per core, {cores} cores); 0 takes one per core")]
pub struct TooManyThreads {
    /// What was asked for.
    pub requested: usize,
    /// The most this machine takes.
    pub limit: usize,
    /// The cores the limit was taken from.
    pub cores: usize,
}

/// The cores this process may run on (1 when unknown).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `requested` if this machine takes it (0 means one per core and is returned as 0), else the
/// error naming the limit.
pub fn checked(requested: usize) -> Result<usize, TooManyThreads> {
    let cores = cores();
    let limit = cores.saturating_mul(OVERSUBSCRIPTION);
    if requested > limit {
        return Err(TooManyThreads { requested, limit, cores });
    }
    Ok(requested)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_up_to_the_limit_pass_and_beyond_it_are_refused_with_it() {
        let limit = cores() * OVERSUBSCRIPTION;
        assert_eq!(checked(0).unwrap(), 0);
        assert_eq!(checked(limit).unwrap(), limit);
        let e = checked(limit + 1).unwrap_err();
        assert_eq!((e.requested, e.limit), (limit + 1, limit));
        assert!(e.to_string().contains(&format!("at most {limit}")), "{e}");
        assert!(checked(100_000).is_err());
    }
}
