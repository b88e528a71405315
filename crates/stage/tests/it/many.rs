//! Several puppets moved in one frame (performers each on their own puppet)
//! are solved side by side: the poses are those of solving them one at a
//! time, and once a drag is under way the thread running the stage's loop
//! allocates nothing for it, the parallel path included.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::Stage;
use puppetry_stage::config::StageConfig;
use puppetry_testkit::alloc;
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

/// Eight gingerbread puppets in two rows of four, with depth ordering on.
fn eight() -> StageConfig {
    let mut text = String::from(STAGE);
    for k in 0..8 {
        let at = centre(k);
        let puppet = Gingerbread::new(&format!("g{k}")).at(at.x, at.y).scale(0.7);
        text.push_str(&puppet.to_string());
    }
    StageConfig::parse("eight.toml", &text, Path::new("/")).unwrap()
}

fn centre(k: usize) -> DVec2 {
    DVec2::new(
        160.0 + 320.0 * (k % 4) as f64,
        180.0 + 360.0 * (k / 4) as f64,
    )
}

/// Performer `p`'s frame `f`: one finger on each of puppets `2p`, `2p+1`,
/// each circling its puppet's centre.
fn frame(p: usize, f: usize) -> ContactFrame {
    let phase = if f == 0 { Phase::Down } else { Phase::Move };
    let a = f as f64 * 0.05;
    let offset = DVec2::new(a.cos() - 1.0, a.sin()) * 30.0;
    ContactFrame {
        source: SourceId::new(format!("performer-{p}")),
        time: f as f64 * 1e-3,
        contacts: (0..2)
            .map(|finger| Contact::new(finger + 1, phase, centre(2 * p + finger as usize) + offset))
            .collect(),
    }
}

fn poses(stage: &Stage) -> Vec<Vec<DVec2>> {
    stage.puppets().iter().map(|p| p.pose().to_vec()).collect()
}

#[test]
fn puppets_moved_together_are_solved_as_one_at_a_time() {
    let config = eight();
    let mut together = Stage::from_config(&config).unwrap();
    let mut alone = Stage::from_config(&config).unwrap();
    for f in 0..12 {
        for p in 0..4 {
            let both = frame(p, f);
            together.apply(&both);
            // Each finger as a source of its own, solved on its own: one
            // puppet at a time.
            for contact in both.contacts {
                alone.apply(&ContactFrame {
                    source: SourceId::new(format!("{}-{}", both.source.as_str(), contact.id)),
                    time: both.time,
                    contacts: vec![contact],
                });
                assert_eq!(alone.solve().len(), 1);
            }
        }
        let solved = together.solve();
        assert_eq!(solved.len(), 8, "every puppet moved in frame {f}");
        assert_eq!(poses(&together), poses(&alone), "frame {f}");
    }
    let rest = Stage::from_config(&config).unwrap();
    for (k, (moved, at_rest)) in poses(&together).iter().zip(poses(&rest)).enumerate() {
        assert!(
            moved
                .iter()
                .zip(&at_rest)
                .any(|(a, b)| a.distance(*b) > 1.0),
            "puppet {k} was dragged"
        );
    }
}

#[test]
fn solving_several_puppets_on_the_stage_pool_does_not_allocate() {
    let config = eight();
    let mut stage = Stage::from_config(&config).unwrap();
    let frames: Vec<Vec<ContactFrame>> = (0..60)
        .map(|f| (0..4).map(|p| frame(p, f)).collect())
        .collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let allocations = pool.install(|| {
        let mut solved = Vec::with_capacity(8);
        let mut step = |stage: &mut Stage, frames: &[ContactFrame]| {
            for frame in frames {
                stage.apply(frame);
            }
            stage.solve_into(&mut solved);
            assert_eq!(solved.len(), 8);
        };
        for frames in &frames[..20] {
            step(&mut stage, frames);
        }
        alloc::start();
        for frames in &frames[20..] {
            step(&mut stage, frames);
        }
        alloc::stop()
    });
    assert_eq!(allocations, 0, "the stage loop's thread allocated");
}
