//! The bundled stage files and assets (`src/bundled.rs`) are compiled in:
//! rebuild when they change.
fn main() {
    println!("cargo:rerun-if-changed=../../config");
    println!("cargo:rerun-if-changed=../../assets");
}
