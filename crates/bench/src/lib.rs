//! What `puppetry` measures, apart from what it serves: the benchmarks of
//! the solvers, rigs and depth order ([`bench`](mod@bench)), of takes
//! ([`take_bench`]) and of the daemon from outside with its relay tier
//! ([`viewers_bench`]); a case timed against another solver on the same
//! problem ([`peers`]); the long-run leak check ([`soak`]); and the lp-FFD
//! paper's comparison of four methods ([`compare`]). A crate of its own so
//! the binary's crate holds only its commands; `puppetry bench`, `soak`,
//! `compare` and `bench-case` call into it. Every public item is
//! documented (`missing_docs` is on here).

pub mod bench;
pub mod compare;
pub mod peers;
pub mod soak;
pub mod take_bench;
pub mod viewers_bench;
