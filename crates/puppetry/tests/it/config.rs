//! Every stage file in `config/` parses and loads, and bad stage files are
//! refused with errors naming the file and the key.

use std::path::{Path, PathBuf};

use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;

fn config_dir() -> PathBuf {
    puppetry_testkit::root().join("config")
}

#[test]
fn every_stage_file_in_config_parses_and_loads() {
    let mut seen = 0;
    for entry in std::fs::read_dir(config_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let config = StageConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
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
            let mut config = StageConfig::load(&path).unwrap();
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
    let config = StageConfig::load(&config_dir().join("demo.toml")).unwrap();
    let stage = Stage::from_config(&config).unwrap();
    assert_eq!(stage.puppets()[0].handles().len(), 2);
}

fn parse_error(text: &str) -> String {
    StageConfig::parse("bad.toml", text, Path::new("/"))
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
    let assets = puppetry_testkit::root().join("assets/gingerbread");
    format!(
        "[stage]\nwidth = 1280\nheight = 720\n[[puppet]]\nname = \"g\"\nimage = \"{}\"\nmesh = \"{}\"\nat = [640, 360]\n{rig}",
        assets.join("gingerbread.png").display(),
        assets.join("gingerbread.mesh.json").display(),
    )
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
        let config = StageConfig::parse("rig.toml", &demo_puppet(rig), Path::new("/")).unwrap();
        let message = Stage::from_config(&config)
            .err()
            .expect("refused")
            .to_string();
        assert!(message.contains(says), "{says}: {message}");
    }
}
