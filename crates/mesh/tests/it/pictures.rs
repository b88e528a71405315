//! Pictures and named files are bounded before anything is allocated: a
//! PNG's size is read from its header and refused past the picture budget
//! (a 1 MB PNG claiming 16384² pixels peaked at 1.6 GB before), a
//! checkerboard's outline is refused before its segments fill memory, and
//! `/dev/zero`, a FIFO or a file past its cap is refused by name at once.

use std::io::Write;
use std::path::Path;

use puppetry_mesh::MeshError;
use puppetry_mesh::file::{self, FileError};
use puppetry_mesh::trace::{trace_png, trace_rgba};

/// A PNG file of `width` × `height` RGBA pixels whose image data is one
/// empty zlib stream: its header alone is a "picture bomb".
fn header_only_png(path: &Path, width: u32, height: u32) {
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let start = out.len();
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        let crc = crc32(&out[start..]);
        out.extend_from_slice(&crc.to_be_bytes());
    }
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 6, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x01, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    chunk(&mut png, b"IEND", &[]);
    std::fs::File::create(path)
        .unwrap()
        .write_all(&png)
        .unwrap();
}

/// CRC-32 (IEEE), as PNG chunks carry it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn size_problem(error: &MeshError) -> String {
    match error {
        MeshError::Invalid(puppetry_mesh::FieldError { field, problem, .. }) if field == "size" => {
            problem.clone()
        }
        other => panic!("expected a size error, got {other}"),
    }
}

#[test]
fn a_png_claiming_16384_squared_pixels_is_refused_from_its_header() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bomb.png");
    header_only_png(&path, 16384, 16384);
    let error = trace_png(&path, 1.0, None).unwrap_err();
    assert!(
        size_problem(&error).contains("MAX_PICTURE_PIXELS"),
        "{error}"
    );
    assert!(
        error.to_string().starts_with(&path.display().to_string()),
        "{error}"
    );
    header_only_png(&path, 40_000, 2);
    let error = trace_png(&path, 1.0, None).unwrap_err();
    assert!(size_problem(&error).contains("MAX_PICTURE_SIDE"), "{error}");
}

#[test]
fn a_checkerboard_outline_is_refused_before_its_segments_fill_memory() {
    let side = 2048u32;
    let rgba: Vec<u8> = (0..side * side)
        .flat_map(|i| {
            let (x, y) = (i % side, i / side);
            let a = if (x + y) % 2 == 0 { 255 } else { 0 };
            [0, 0, 0, a]
        })
        .collect();
    let error = trace_rgba("board", side, side, &rgba, 1.0, None).unwrap_err();
    assert!(
        error.to_string().contains("MAX_OUTLINE_SEGMENTS"),
        "{error}"
    );
}

#[test]
fn dev_zero_a_fifo_and_a_file_past_its_cap_are_refused_by_name() {
    let error = puppetry_mesh::Mesh::load(Path::new("/dev/zero")).unwrap_err();
    assert!(
        matches!(&error, MeshError::File(FileError::NotAFile { .. })),
        "{error}"
    );
    assert!(error.to_string().starts_with("/dev/zero:"), "{error}");
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.mesh.json");
    if std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success())
    {
        // Before the fix, opening it blocked for ever waiting for a writer.
        let error = puppetry_mesh::Mesh::load(&fifo).unwrap_err();
        assert!(error.to_string().contains("FIFO"), "{error}");
    }
    let big = dir.path().join("big.mesh.json");
    let f = std::fs::File::create(&big).unwrap();
    f.set_len(file::MESH_FILE.bytes + 1).unwrap();
    let error = puppetry_mesh::Mesh::load(&big).unwrap_err();
    assert!(error.to_string().contains("MAX_MESH_FILE_BYTES"), "{error}");
}
