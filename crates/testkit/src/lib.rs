//! What the workspace's tests share, written once: small meshes and a dense
//! least-squares reference of the ARAP energies ([`fixtures`]), an
//! allocation counter for the no-allocation tests ([`alloc`]), a
//! pseudo-terminal standing in for a serial pad ([`pty`]), TUIO bundles as a
//! table sends them ([`tuio`]), the fuzz tests' case count and input makers
//! ([`fuzz`]), what the simulated shows share ([`simulate`]), the stage
//! files tests write ([`stage_text`]), and where the checkout's files are
//! ([`root`]). A dev-dependency only: nothing here ships. Every public item
//! is documented (`missing_docs` is on here).

pub mod alloc;
pub mod fixtures;
pub mod fuzz;
pub mod pty;
pub mod simulate;
pub mod sound;
pub mod stage_text;
pub mod tuio;

pub use fixtures::*;

use std::path::PathBuf;

/// The workspace root: `config/`, `assets/`, `clients/` and `tests/` are
/// beneath it (and `../shared` beside it, in CI).
pub fn root() -> PathBuf {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    here.parent()
        .and_then(|crates| crates.parent())
        .expect("crates/testkit sits two levels below the workspace root")
        .to_path_buf()
}
