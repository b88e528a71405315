//! Curve puppets end to end, on the bundled curve stage
//! (`config/curve.toml`): the stage message describes each stroke, its
//! texture is served, a performer's drag peels it over the wire, and a take
//! of the replayed rope pull replays bit for bit and exports with the
//! stroke's colour where the rope is.

use std::time::{Duration, Instant};

use futures_util::SinkExt;
use glam::DVec2;
use puppetry_daemon::config::ShowConfig;
use puppetry_daemon::serve::{Options, Running, start_with};
use puppetry_daemon::stream::WebFiles;
use puppetry_input::config::InputConfig;
use puppetry_stage::Stage;
use puppetry_take::replay::verify;
use puppetry_take::{Record, TakeReader};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::common::daemon::*;

fn curve_stage(keep_replay: bool) -> ShowConfig {
    let mut config = ShowConfig::load(&root().join("config/curve.toml")).unwrap();
    config.stage.listen = "127.0.0.1:0".parse().unwrap();
    if keep_replay {
        for input in &mut config.inputs {
            // Played once at its own pace (4 s), so the stage solves
            // between its frames as it would on a show.
            if let InputConfig::Replay { repeat, .. } = input {
                *repeat = false;
            }
        }
    } else {
        config.inputs.clear();
    }
    config
}

/// A puppet's centre line from the stage message: the midpoints of its
/// ribbon's vertex pairs.
fn centre_line(vertices: &[DVec2]) -> Vec<DVec2> {
    vertices
        .chunks_exact(2)
        .map(|pair| (pair[0] + pair[1]) / 2.0)
        .collect()
}

fn points(value: &Value) -> Vec<DVec2> {
    let flat: Vec<f64> = serde_json::from_value(value.clone()).unwrap();
    flat.chunks(2).map(|c| DVec2::new(c[0], c[1])).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_curve_stage_describes_its_strokes_and_a_drag_peels_one() {
    let config = curve_stage(false);
    let running = start_with(&config, Options::new(WebFiles::Embedded))
        .await
        .unwrap();
    let (mut ws, stage) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "demo"}),
    )
    .await;
    let rope = &stage["puppets"][1];
    assert_eq!(rope["name"], "rope");
    assert_eq!(rope["rig"]["kind"], "curve");
    assert_eq!(rope["rig"]["width"], 14.0);
    let rest_line = rope["rig"]["line"].as_array().unwrap().len();
    assert_eq!(points(&rope["rest"]).len(), 2 * rest_line);

    // The stroke's texture is a PNG of its colour.
    let answer = http_get(running.address, "/puppets/1/texture.png").await;
    assert_eq!(http_status(&answer), 200);
    let body = &answer[answer.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4..];
    assert!(body.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG");

    // Drag the ribbon (puppet 2) near one end, straight down 60.
    let ribbon = &stage["puppets"][2];
    let rest = centre_line(&points(&ribbon["rest"]));
    let last = rest.len() - 1;
    let grab = rest[last - 8];
    let to = grab - DVec2::new(0.0, 60.0);
    let contact = |phase: &str, at: DVec2| {
        Message::text(
            json!({"type": "contacts", "contacts": [
                {"id": 1, "phase": phase, "x": at.x, "y": at.y}]})
            .to_string(),
        )
    };
    ws.send(contact("down", grab)).await.unwrap();
    for step in 1..=12 {
        ws.send(contact("move", grab.lerp(to, step as f64 / 12.0)))
            .await
            .unwrap();
    }
    let frame = frame_until(&mut ws, |f| {
        f.puppet == 2 && centre_line(&f.vertices)[last - 8].distance(to) < 0.5
    })
    .await;
    let now = centre_line(&frame.vertices);
    // The far end is outside the peeled region (150 along the curve): it
    // has not moved.
    assert!(
        now[0].distance(rest[0]) < 1e-3,
        "{} from {}",
        now[0],
        rest[0]
    );
    // The stroke keeps its width: each vertex pair stays 10 (to the mitre)
    // apart.
    for pair in frame.vertices.chunks_exact(2) {
        let width = pair[0].distance(pair[1]);
        assert!((10.0 - 1e-3..=20.0 + 1e-3).contains(&width), "{width}");
    }
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_take_of_the_rope_pull_replays_bit_for_bit_and_exports_the_stroke() {
    let config = curve_stage(true);
    let dir = tempfile::tempdir().unwrap();
    let mut options = Options::new(WebFiles::Embedded);
    options.takes_dir = dir.path().to_path_buf();
    options.record = true;
    let running = start_with(&config, options).await.unwrap();
    finish(running).await;
    let take = std::fs::read_dir(dir.path())
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let rope_frames = TakeReader::open(&take)
        .unwrap()
        .filter(|r| matches!(r, Ok(Record::Frame(f)) if f.puppet == 1))
        .count();
    assert!(rope_frames > 20, "{rope_frames} rope frames");

    // The steps replayed into a fresh stage give every frame, bit for bit.
    let v = verify(&take, Stage::from_config(&config).unwrap()).unwrap();
    assert_eq!(v.first_mismatch, None);

    // Exported, the first and last frames show the rope's colour, and it
    // has swung: its pixels are somewhere else.
    let animation =
        puppetry_export::take::animation_of_take(&take, &config, 30.0, None, None).unwrap();
    let textures = puppetry_export::raster::textures(&animation);
    let (w, h) = (320u32, 180u32);
    let mut raster = puppetry_export::raster::Rasterizer::new(&animation, &textures, w, h);
    let rope_pixels = |raster: &mut puppetry_export::raster::Rasterizer, frame: usize| {
        let mut out = vec![0u8; (w * h * 4) as usize];
        raster.render(frame, &mut out);
        out.chunks_exact(4)
            .enumerate()
            .filter(|(_, px)| {
                px[3] == 255
                    && px[0].abs_diff(0x9c) < 8
                    && px[1].abs_diff(0x4a) < 8
                    && px[2].abs_diff(0x1a) < 8
            })
            .map(|(i, _)| i)
            .collect::<Vec<_>>()
    };
    let first = rope_pixels(&mut raster, 0);
    let middle = rope_pixels(&mut raster, animation.frame_count / 4);
    assert!(first.len() > 50, "{} rope pixels", first.len());
    assert!(middle.len() > 50, "{} rope pixels", middle.len());
    assert_ne!(first, middle, "the rope swung");
}

async fn finish(running: Running) {
    let deadline = Instant::now() + PLAYS;
    while !running.inputs_done() {
        assert!(Instant::now() < deadline, "the inputs did not end");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    running.shutdown().await;
}

/// `add_curve`: a director's drawn stroke becomes a curve puppet on every
/// client where it was drawn; performers may not; bad strokes are refused
/// naming the field.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_director_draws_a_curve_puppet_and_bad_strokes_are_refused() {
    let config = curve_stage(false);
    let running = start_with(&config, Options::new(WebFiles::Embedded))
        .await
        .unwrap();
    let (mut director, _) = connect(
        &running,
        json!({"type": "hello", "role": "director", "token": "director"}),
    )
    .await;
    let (mut performer, _) = connect(
        &running,
        json!({"type": "hello", "role": "performer", "token": "demo"}),
    )
    .await;
    let stroke: Vec<[f64; 2]> = (0..30)
        .map(|i| {
            [
                400.0 + 10.0 * i as f64,
                650.0 + 20.0 * (i as f64 / 5.0).sin(),
            ]
        })
        .collect();
    let add = |points: &Vec<[f64; 2]>, width: f64, colour: &str| {
        Message::text(
            json!({"type": "add_curve", "name": "drawn", "points": points,
                   "width": width, "colour": colour})
            .to_string(),
        )
    };
    performer.send(add(&stroke, 8.0, "#336699")).await.unwrap();
    assert_eq!(next_error(&mut performer).await["code"], "forbidden");
    for (points, width, colour, field) in [
        (stroke[..2].to_vec(), 8.0, "#336699", "points"),
        (stroke.clone(), 0.0, "#336699", "width"),
        (stroke.clone(), 8.0, "blue", "colour"),
    ] {
        director.send(add(&points, width, colour)).await.unwrap();
        let m = next_error(&mut director).await;
        assert_eq!(m["field"], field, "{m}");
    }
    director.send(add(&stroke, 8.0, "#336699")).await.unwrap();
    let added = loop {
        let m = next_text(&mut director).await;
        if m["type"] == "puppet_added" {
            break m;
        }
    };
    assert_eq!(added["name"], "drawn");
    let id = added["puppet"].as_u64().unwrap();
    // Every client gets the new stage, the stroke where it was drawn.
    let stage = loop {
        let m = next_text(&mut performer).await;
        if m["type"] == "stage" && m["puppets"].as_array().unwrap().len() == 4 {
            break m;
        }
    };
    let puppet = &stage["puppets"][3];
    assert_eq!(puppet["id"].as_u64().unwrap(), id);
    assert_eq!(puppet["rig"]["kind"], "curve");
    let line = centre_line(&points(&puppet["rest"]));
    // (The stage message's rest positions are single precision.)
    let first = DVec2::from(stroke[0]);
    let last = DVec2::from(stroke[29]);
    assert!(line[0].distance(first) < 1e-3, "{}", line[0]);
    assert!(
        line.last().unwrap().distance(last) < 1e-3,
        "{} {last}",
        line.last().unwrap()
    );
    running.shutdown().await;
}

async fn next_error(ws: &mut Client) -> Value {
    loop {
        let m = next_text(ws).await;
        if m["type"] == "error" {
            return m;
        }
    }
}
