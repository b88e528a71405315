//! The web client (`src/stream/edge.rs`) and the bundled stage files and
//! assets (`src/bundled.rs`) are compiled in: rebuild when they change.
fn main() {
    println!("cargo:rerun-if-changed=../../clients/web");
    println!("cargo:rerun-if-changed=../../config");
    println!("cargo:rerun-if-changed=../../assets");
}
