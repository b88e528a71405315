//! Every stage file in `config/` parses and loads, and bad stage files are
//! refused with errors naming the file and the key.

use std::path::{Path, PathBuf};

use puppetry_daemon::config::ShowConfig;
use puppetry_stage::Stage;
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

fn config_dir() -> PathBuf {
    puppetry_testkit::root().join("config")
}

#[test]
fn every_stage_file_in_config_parses_and_loads() {
    let mut seen = 0;
    for entry in std::fs::read_dir(config_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let config = ShowConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
            let stage =
                Stage::from_config(&config).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(stage.puppets().len(), config.puppets.len());
            seen += 1;
        }
    }
    assert!(seen >= 1, "config/ holds the demo stage");
}

#[tokio::test]
async fn every_stage_file_in_config_starts_with_its_inputs() {
    for entry in std::fs::read_dir(config_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let mut config = ShowConfig::load(&path).unwrap();
            config.stage.listen = "127.0.0.1:0".parse().unwrap();
            let web = puppetry_daemon::stream::WebFiles::Embedded;
            let running = puppetry_daemon::serve::start(&config, web, None)
                .await
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            running.shutdown().await;
        }
    }
}

#[test]
fn the_demo_stage_pins_the_feet() {
    let config = ShowConfig::load(&config_dir().join("demo.toml")).unwrap();
    let stage = Stage::from_config(&config).unwrap();
    assert_eq!(stage.puppets()[0].handles().len(), 2);
}

fn parse_error(text: &str) -> String {
    ShowConfig::parse("bad.toml", text, Path::new("/"))
        .unwrap_err()
        .to_string()
}

#[test]
fn bad_stage_files_are_named_and_explained() {
    let base = "[stage]\nwidth = 100\nheight = 100\n";
    let message = parse_error(&format!("{base}colour = 3\n"));
    assert!(
        message.contains("bad.toml") && message.contains("colour"),
        "{message}"
    );
    let message = parse_error("[stage]\nwidth = -1\nheight = 100\n");
    assert!(
        message.contains("stage") && message.contains("positive"),
        "{message}"
    );
    let message = parse_error(&format!(
        "{base}[[puppet]]\nname = \"a\"\nimage = \"a.png\"\nmesh = \"a.json\"\nat = [0, 0]\nscale = 0\n"
    ));
    assert!(message.contains("puppet[0].scale"), "{message}");
    let message = parse_error(&format!("{base}[[input]]\nkind = \"teleport\"\n"));
    assert!(message.contains("teleport"), "{message}");
    let message = parse_error("[stage]\nwidth = 100\n");
    assert!(message.contains("height"), "{message}");
}

fn demo_puppet(rig: &str) -> String {
    format!("{STAGE}{}{rig}", Gingerbread::new("g"))
}

#[test]
fn bad_rig_sections_are_named_and_explained() {
    let grid = "[puppet.grid]\ncolumns = 10\nrows = 10\n";
    let skeleton = "[puppet.skeleton]\njoints = [[256, 182], [256, 297]]\nbones = [[0, 1]]\n";
    for (rig, says) in [
        (format!("{grid}{skeleton}"), "one rig"),
        (
            "[puppet.grid]\ncolumns = 1\nrows = 10\n".to_string(),
            "puppet[0].grid.columns",
        ),
        (format!("{grid}colour = 1\n"), "colour"),
        (format!("{grid}locality = -1\n"), "puppet[0].grid.locality"),
        (format!("{grid}basis = \"hexagon\"\n"), "hexagon"),
        (
            format!("{grid}iterations = 0\n"),
            "puppet[0].grid.iterations",
        ),
        (format!("{skeleton}mode = \"ik\"\n"), "ik"),
        (format!("pins = [[168, 58]]\n{skeleton}"), "puppet[0].pins"),
        (
            format!(
                "{skeleton}[[puppet.skeleton.poses]]\nname = \"a\"\n[[puppet.skeleton.poses]]\nname = \"a\"\n"
            ),
            "puppet[0].skeleton.poses[1].name",
        ),
        (
            format!("{skeleton}[puppet.skeleton.params]\nroundz = 3\n"),
            "roundz",
        ),
    ] {
        let message = parse_error(&demo_puppet(&rig));
        assert!(
            message.contains("bad.toml") && message.contains(says),
            "{says}: {message}"
        );
    }
}

#[test]
fn rigs_the_deformers_refuse_are_named_by_file_puppet_and_field() {
    for (rig, says) in [
        // A bone cycle.
        (
            "[puppet.skeleton]\njoints = [[256, 182], [256, 297]]\nbones = [[0, 1], [1, 0]]\n",
            "rig.toml: puppet[0] (g).skeleton.bones",
        ),
        // A joint off the mesh.
        (
            "[puppet.skeleton]\njoints = [[256, 182], [5000, 297]]\nbones = [[0, 1]]\n",
            "rig.toml: puppet[0] (g).skeleton.joints",
        ),
        // A key pose of the wrong shape.
        (
            "[puppet.skeleton]\njoints = [[256, 182], [256, 297]]\nbones = [[0, 1]]\n[[puppet.skeleton.poses]]\nname = \"a\"\nangles = [1, 2]\n",
            "rig.toml: puppet[0] (g).skeleton.poses[0]",
        ),
        (
            "[puppet.grid]\ncolumns = 40\nrows = 40\n",
            "rig.toml: puppet[0] (g).grid",
        ),
    ] {
        let config = ShowConfig::parse("rig.toml", &demo_puppet(rig), Path::new("/")).unwrap();
        let message = Stage::from_config(&config)
            .err()
            .expect("refused")
            .to_string();
        assert!(message.contains(says), "{says}: {message}");
    }
}

/// The skeleton stage's "cheer" key pose solved on the stage: both hands
/// (joints 6 and 9) and the mesh around them end well above where they
/// rest and above the shoulders. The stage is y up (origin bottom-left),
/// so up is a larger y.
#[test]
fn the_skeleton_stages_cheer_raises_both_hands() {
    let config = ShowConfig::load(&config_dir().join("skeleton.toml")).unwrap();
    let mut stage = Stage::from_config(&config).unwrap();
    stage.solve();
    let joints = |stage: &Stage| stage.puppets()[0].rig().points().unwrap().to_vec();
    let rest = joints(&stage);
    let rest_pose = stage.puppets()[0].pose().to_vec();
    stage.set_key_pose(0, "rest", "cheer", 1.0).unwrap();
    stage.solve();
    let cheer = joints(&stage);
    let pose = stage.puppets()[0].pose();
    for (hand, shoulder) in [(6, 4), (9, 7)] {
        let rose = cheer[hand].y - rest[hand].y;
        assert!(
            rose > 50.0 && cheer[hand].y > cheer[shoulder].y,
            "hand {hand}: {:?} at rest, {:?} cheering (shoulder at {:?})",
            rest[hand],
            cheer[hand],
            cheer[shoulder]
        );
        // The picture follows the joint: the vertices about the hand rise.
        let near: Vec<usize> = (0..rest_pose.len())
            .filter(|&v| rest_pose[v].distance(rest[hand]) < 20.0)
            .collect();
        assert!(!near.is_empty(), "vertices about hand {hand}");
        let mean_rise = near
            .iter()
            .map(|&v| pose[v].y - rest_pose[v].y)
            .sum::<f64>()
            / near.len() as f64;
        assert!(mean_rise > 50.0, "hand {hand}'s vertices rose {mean_rise}");
    }
}

/// Runs `puppetry ARGS`, expects it to fail, and returns its stderr.
fn binary_fails(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_puppetry"))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{args:?} succeeded: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

#[test]
fn a_toml_error_keeps_its_lines_and_the_marker_points_at_the_typo() {
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("typo.toml");
    // Line 3: a value that is not TOML (a word without quotes).
    std::fs::write(&stage, "[stage]\nwidth = 1280\nheight = sevenhundred\n").unwrap();
    let stderr = binary_fails(&["serve", "--config", stage.to_str().unwrap()]);
    assert!(
        stderr.contains("typo.toml") && stderr.contains("line 3"),
        "{stderr}"
    );
    let lines: Vec<&str> = stderr.lines().collect();
    let quoted = lines
        .iter()
        .position(|l| l.contains("height = sevenhundred"))
        .unwrap_or_else(|| panic!("the line is quoted on a line of its own: {stderr}"));
    let marker = lines
        .get(quoted + 1)
        .filter(|l| l.contains('^'))
        .unwrap_or_else(|| panic!("a ^ marker under the line: {stderr}"));
    assert_eq!(
        marker.find('^'),
        lines[quoted].find("sevenhundred"),
        "the marker points at the typo:\n{stderr}"
    );
}

#[test]
fn a_stage_file_copied_elsewhere_says_its_paths_are_relative_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let copied = dir.path().join("shows");
    std::fs::create_dir(&copied).unwrap();
    let stage = copied.join("demo.toml");
    std::fs::copy(config_dir().join("demo.toml"), &stage).unwrap();
    let stderr = binary_fails(&["serve", "--config", stage.to_str().unwrap()]);
    // Tempdirs are absolute paths: shown as given, `..` taken back.
    let folder = copied.clone();
    let became = dir.path().join("assets/gingerbread/gingerbread.png");
    for says in [
        "demo.toml",
        "puppet[0].image",
        "../assets/gingerbread/gingerbread.png",
        "relative to the stage file's folder",
        folder.to_str().unwrap(),
        became.to_str().unwrap(),
    ] {
        assert!(stderr.contains(says), "{says:?} in {stderr}");
    }
}
