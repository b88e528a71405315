//! Sample and hold: frame k shows the newest recorded frame at or before
//! `from + k / fps`; bad ranges and rates name their flag.

use puppetry_export::resample::{frame_count, resample, sample_and_hold};

#[test]
fn frames_hold_the_newest_recording() {
    // Recorded at irregular times; exported at 10 fps from 0.0 to 0.6.
    let times = [0.05, 0.1, 0.12, 0.31, 0.31, 0.5];
    let picked = sample_and_hold(&times, 10.0, 0.0, 0.6).unwrap();
    // t = 0.0 (nothing yet), 0.1 (exactly the second), 0.2, 0.3 (still the
    // third), 0.4 (the later of two equal times), 0.5 (exact).
    assert_eq!(picked, [None, Some(1), Some(2), Some(2), Some(4), Some(5)]);
    let frames = ["a", "b", "c", "d", "e", "f"];
    let out = resample(&times, &frames, &"rest", 10.0, 0.0, 0.6).unwrap();
    assert_eq!(out, ["rest", "b", "c", "c", "e", "f"]);
    // A later start.
    let out = resample(&times, &frames, &"rest", 10.0, 0.3, 0.55).unwrap();
    assert_eq!(out, ["c", "e", "f"]);
}

#[test]
fn frame_counts_cover_from_up_to_before_to() {
    assert_eq!(frame_count(30.0, 0.0, 1.0).unwrap(), 30);
    assert_eq!(frame_count(30.0, 0.0, 1.01).unwrap(), 31);
    assert_eq!(frame_count(60.0, 2.0, 62.0).unwrap(), 3600);
    assert_eq!(frame_count(30.0, 0.0, 0.001).unwrap(), 1);
    assert_eq!(frame_count(0.1 + 0.2, 0.0, 10.0).unwrap(), 3);
}

#[test]
fn bad_ranges_and_rates_name_their_flag() {
    let err = |r: Result<usize, puppetry_export::ExportError>| r.unwrap_err().to_string();
    assert!(
        err(frame_count(30.0, 2.0, 2.0)).starts_with("--to: must be after --from (2 s), got 2 s")
    );
    assert!(err(frame_count(30.0, 3.0, 2.0)).starts_with("--to: must be after --from"));
    assert!(err(frame_count(0.0, 0.0, 1.0)).starts_with("--fps: must be a positive frame rate"));
    assert!(err(frame_count(f64::NAN, 0.0, 1.0)).starts_with("--fps: "));
    assert!(err(frame_count(-5.0, 0.0, 1.0)).starts_with("--fps: "));
    assert!(err(frame_count(f64::INFINITY, 0.0, 1.0)).starts_with("--fps: "));
    assert!(err(frame_count(30.0, f64::NAN, 1.0)).starts_with("--from: "));
    assert!(err(frame_count(30.0, 0.0, f64::INFINITY)).starts_with("--to: "));
    let bad_times = sample_and_hold(&[0.0, 0.2, 0.1], 30.0, 0.0, 1.0)
        .unwrap_err()
        .to_string();
    assert_eq!(bad_times, "times[2]: 0.1 s is before times[1] = 0.2 s");
    let mismatch = resample(&[0.0], &[1, 2], &0, 30.0, 0.0, 1.0)
        .unwrap_err()
        .to_string();
    assert!(
        mismatch.starts_with("frames: has 2 entries but times has 1"),
        "{mismatch}"
    );
}
