//! The web client is compiled in (`src/stream/edge.rs`): rebuild when it
//! changes.
fn main() {
    println!("cargo:rerun-if-changed=../../clients/web");
}
